// fluxcal._core — conversion only: NumPy ⇄ Eigen, fluxcal::Error → ValueError. No logic here.
#include <fluxcal/coverage.hpp>
#include <fluxcal/ellipsoid.hpp>

#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;
using namespace pybind11::literals;

namespace {

py::dict summary_dict(const fluxcal::Summary& s) {
  return py::dict("samples"_a = s.samples, "iterations"_a = s.iterations, "cost"_a = s.cost,
                  "residual_rms"_a = s.residual_rms, "norm_mean"_a = s.norm_mean,
                  "norm_std_over_mean"_a = s.norm_std_over_mean, "condition_number"_a = s.condition_number,
                  "coverage_ratio"_a = s.coverage_ratio,
                  "direction_coverage"_a = s.direction_coverage, "exact_statistics"_a = s.exact_statistics,
                  "converged"_a = s.converged, "message"_a = s.message, "warnings"_a = s.warnings);
}

py::dict result_dict(const fluxcal::EllipsoidResult& r) {
  const auto& c = r.calibration;
  return py::dict("offset"_a = c.offset, "matrix"_a = c.matrix, "field_norm"_a = c.field_norm,
                  "units"_a = c.units, "model"_a = c.model, "summary"_a = summary_dict(r.summary),
                  "quadric"_a = r.quadric);
}

void bind_options(py::module_& m) {
  py::class_<fluxcal::EllipsoidOptions>(m, "EllipsoidOptions")
      .def(py::init<>())
      .def_readwrite("field_norm", &fluxcal::EllipsoidOptions::field_norm)
      .def_readwrite("units", &fluxcal::EllipsoidOptions::units)
      .def_readwrite("planar_ratio", &fluxcal::EllipsoidOptions::planar_ratio)
      .def_readwrite("poor_coverage_ratio", &fluxcal::EllipsoidOptions::poor_coverage_ratio)
      .def_readwrite("poor_direction_coverage", &fluxcal::EllipsoidOptions::poor_direction_coverage)
      .def_readwrite("exact_statistics", &fluxcal::EllipsoidOptions::exact_statistics)
      .def_readwrite("coverage_rows", &fluxcal::EllipsoidOptions::coverage_rows);
}

}  // namespace

PYBIND11_MODULE(_core, m) {
  m.doc() = "fluxcal C++ core (use the fluxcal package, not this module)";
  m.attr("__version__") = fluxcal::version();
  py::register_exception<fluxcal::Error>(m, "Error", PyExc_ValueError);

  bind_options(m);
  // samples arrive as a C-contiguous float64 (N, 3) array (the Python layer ensures it): no copy.
  m.def(
      "fit_ellipsoid",
      [](const fluxcal::SamplesRef& samples, const fluxcal::EllipsoidOptions& options) {
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
      .def("add_rows", &fluxcal::EllipsoidMoments::add_rows, "readings"_a.noconvert())
      .def("merge", &fluxcal::EllipsoidMoments::merge, "other"_a)
      .def_property_readonly("count", &fluxcal::EllipsoidMoments::count)
      .def_property_readonly("centre", &fluxcal::EllipsoidMoments::centre)
      .def_property_readonly("scale", &fluxcal::EllipsoidMoments::scale)
      .def("scatter", &fluxcal::EllipsoidMoments::scatter)
      .def("fit", [](const fluxcal::EllipsoidMoments& mom, const fluxcal::EllipsoidOptions& options) {
        return result_dict(fluxcal::fit_ellipsoid(mom, options));
      }, "options"_a);

  m.def("direction_coverage", py::overload_cast<const fluxcal::SamplesRef&, Eigen::Index>(&fluxcal::direction_coverage),
        "fields"_a.noconvert(), "max_rows"_a = 0);
  m.def("direction_bin", py::overload_cast<const Eigen::Vector3d&>(&fluxcal::direction_bin), "v"_a);
  m.def("normalisation", [](const fluxcal::SamplesRef& s) { return fluxcal::normalisation(s); },
        "samples"_a.noconvert());
}
