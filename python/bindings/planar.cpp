// Bindings of planar.hpp.
#include "bindings.hpp"

#include <fluxcal/planar.hpp>

using namespace pybind11::literals;

namespace fluxcal_py {

namespace {

py::dict planar_dict(const fluxcal::PlanarResult& r) {
  return py::dict("offset"_a = r.offset, "matrix"_a = r.matrix, "field_norm"_a = r.field_norm,
                  "relative_scale"_a = r.relative_scale, "parameters"_a = r.parameters,
                  "parameter_names"_a = r.parameter_names, "covariance"_a = r.covariance,
                  "standard_errors"_a = r.standard_errors, "determined"_a = r.determined,
                  "identifiable"_a = r.identifiable, "sigma"_a = r.sigma, "rss"_a = r.rss,
                  "mean_radius"_a = r.mean_radius, "fisher_condition"_a = r.fisher_condition, "start"_a = r.start,
                  "residuals"_a = r.residuals, "units"_a = r.units,
                  "serial_correlation"_a = serial_correlation_dict(r.serial_correlation),
                  "summary"_a = summary_dict(r.summary));
}

}  // namespace

void bind_planar(py::module_& m) {
  using fluxcal::PlanarOptions;
  using fluxcal::PlanarShape;
  py::enum_<PlanarShape>(m, "PlanarShape")
      .value("circle", PlanarShape::circle)
      .value("diagonal", PlanarShape::diagonal)
      .value("symmetric", PlanarShape::symmetric);

  py::class_<fluxcal::PlanarStart>(m, "PlanarStart")
      .def(py::init<>())
      .def(py::init([](const Eigen::Vector2d& offset, const Eigen::Matrix2d& matrix) {
             return fluxcal::PlanarStart{offset, matrix};
           }),
           "offset"_a, "matrix"_a)
      .def_readwrite("offset", &fluxcal::PlanarStart::offset)
      .def_readwrite("matrix", &fluxcal::PlanarStart::matrix);

  py::class_<PlanarOptions>(m, "PlanarOptions")
      .def(py::init<>())
      .def_readwrite("shape", &PlanarOptions::shape)
      .def_readwrite("field_norm", &PlanarOptions::field_norm)
      .def_readwrite("max_iterations", &PlanarOptions::max_iterations)
      .def_readwrite("tolerance", &PlanarOptions::tolerance)
      .def_readwrite("noise_bias_correction", &PlanarOptions::noise_bias_correction)
      .def_readwrite("determined_tolerance", &PlanarOptions::determined_tolerance)
      .def_readwrite("min_radius_over_noise", &PlanarOptions::min_radius_over_noise)
      .def_readwrite("serial_correlation", &PlanarOptions::serial_correlation)
      .def_readwrite("serial_correlation_alpha", &PlanarOptions::serial_correlation_alpha)
      .def_readwrite("start", &PlanarOptions::start)
      .def_readwrite("units", &PlanarOptions::units);

  // readings arrive as a C-contiguous float64 (N, 2) array and field_norms as float64 (N,) or None (the Python
  // layer ensures it): no copy. None: options.field_norm (0: a relative scale).
  m.def(
      "fit_planar",
      [](const fluxcal::Readings2DRef::Base& readings,
         const std::optional<Eigen::Ref<const Eigen::VectorXd>>& field_norms, const PlanarOptions& options) {
        fluxcal::PlanarResult r;
        {
          py::gil_scoped_release release;
          r = field_norms ? fluxcal::fit_planar(readings, *field_norms, options)
                          : fluxcal::fit_planar(readings, options);
        }
        return planar_dict(r);
      },
      "readings"_a.noconvert(), "field_norms"_a.noconvert() = py::none(), "options"_a = PlanarOptions());
}

}  // namespace fluxcal_py
