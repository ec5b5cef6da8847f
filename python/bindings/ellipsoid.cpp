// Bindings of ellipsoid.hpp and coverage.hpp.
#include "bindings.hpp"

#include <fluxcal/coverage.hpp>
#include <fluxcal/ellipsoid.hpp>

using namespace pybind11::literals;

namespace fluxcal_py {
namespace {

py::dict result_dict(const fluxcal::EllipsoidResult& r) {
  py::dict d = calibration_dict(r.calibration, r.summary);
  d["quadric"] = r.quadric;
  d["noise_sigma"] = r.noise_sigma;
  return d;
}

}  // namespace

void bind_ellipsoid(py::module_& m) {
  using fluxcal::EllipsoidOptions;
  py::enum_<fluxcal::EllipsoidMethod>(m, "EllipsoidMethod")
      .value("ordinary", fluxcal::EllipsoidMethod::ordinary)
      .value("adjusted", fluxcal::EllipsoidMethod::adjusted);
  py::class_<EllipsoidOptions>(m, "EllipsoidOptions")
      .def(py::init<>())
      .def_readwrite("method", &EllipsoidOptions::method)
      .def_readwrite("field_norm", &EllipsoidOptions::field_norm)
      .def_readwrite("units", &EllipsoidOptions::units)
      .def_readwrite("planar_ratio", &EllipsoidOptions::planar_ratio)
      .def_readwrite("poor_coverage_ratio", &EllipsoidOptions::poor_coverage_ratio)
      .def_readwrite("poor_direction_coverage", &EllipsoidOptions::poor_direction_coverage)
      .def_readwrite("exact_statistics", &EllipsoidOptions::exact_statistics)
      .def_readwrite("coverage_rows", &EllipsoidOptions::coverage_rows);

  // samples arrive as a C-contiguous float64 (N, 3) array (the Python layer ensures it): no copy.
  m.def(
      "fit_ellipsoid",
      [](const fluxcal::SamplesView& samples, const EllipsoidOptions& options) {
        fluxcal::EllipsoidResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::fit_ellipsoid(samples, options);
        }
        return result_dict(r);
      },
      "samples"_a.noconvert(), "options"_a);

  py::class_<fluxcal::EllipsoidMoments>(m, "EllipsoidMoments")
      .def(py::init<const Eigen::Vector3d&, double>(), "centre"_a, "scale"_a)
      .def("add_rows", [](fluxcal::EllipsoidMoments& mom, const fluxcal::SamplesView& readings) {
        mom.add_rows(readings);
      }, "readings"_a.noconvert())
      .def("merge", &fluxcal::EllipsoidMoments::merge, "other"_a)
      .def_property_readonly("count", &fluxcal::EllipsoidMoments::count)
      .def_property_readonly("centre", &fluxcal::EllipsoidMoments::centre)
      .def_property_readonly("scale", &fluxcal::EllipsoidMoments::scale)
      .def("scatter", &fluxcal::EllipsoidMoments::scatter)
      .def("fit", [](const fluxcal::EllipsoidMoments& mom, const EllipsoidOptions& options) {
        return result_dict(fluxcal::fit_ellipsoid(mom, options));
      }, "options"_a);

  m.def("normalisation", [](const fluxcal::SamplesView& s) { return fluxcal::normalisation(s); },
        "samples"_a.noconvert());
  m.def("direction_coverage",
        [](const fluxcal::SamplesView& fields, Eigen::Index max_rows) {
          return fluxcal::direction_coverage(fields, max_rows);
        },
        "fields"_a.noconvert(), "max_rows"_a = 0);
  m.def("direction_bin", py::overload_cast<const Eigen::Vector3d&>(&fluxcal::direction_bin), "v"_a);
}

}  // namespace fluxcal_py
