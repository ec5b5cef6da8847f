// fluxcal._core — conversion only: NumPy ⇄ Eigen, fluxcal::Error → ValueError. No logic here.
// One bind_* per capability, each in its own file (bindings.hpp).
#include "bindings.hpp"

using namespace pybind11::literals;

namespace fluxcal_py {

py::dict summary_dict(const fluxcal::Summary& s) {
  return py::dict("samples"_a = s.samples, "iterations"_a = s.iterations, "cost"_a = s.cost,
                  "residual_rms"_a = s.residual_rms, "norm_mean"_a = s.norm_mean,
                  "norm_std_over_mean"_a = s.norm_std_over_mean, "condition_number"_a = s.condition_number,
                  "coverage_ratio"_a = s.coverage_ratio, "direction_coverage"_a = s.direction_coverage,
                  "direction_eigenvalues"_a = std::vector<double>(s.direction_eigenvalues.data(), s.direction_eigenvalues.data() + 3),
                  "exact_statistics"_a = s.exact_statistics, "converged"_a = s.converged,
                  "message"_a = s.message, "warnings"_a = s.warnings);
}

py::dict serial_correlation_dict(const fluxcal::SerialCorrelationReport& r) {
  const Eigen::VectorXd& se = r.standard_errors_independent;
  return py::dict("lag1"_a = r.lag1, "ljung_box_p"_a = r.ljung_box_p, "lags"_a = r.lags, "inflation"_a = r.inflation,
                  "standard_errors_independent"_a = std::vector<double>(se.data(), se.data() + se.size()));
}

py::dict calibration_dict(const fluxcal::Calibration& c, const fluxcal::Summary& s) {
  return py::dict("offset"_a = c.offset, "matrix"_a = c.matrix, "field_norm"_a = c.field_norm,
                  "units"_a = c.units, "model"_a = c.model, "summary"_a = summary_dict(s));
}

}  // namespace fluxcal_py

PYBIND11_MODULE(_core, m) {
  m.doc() = "fluxcal C++ core (use the fluxcal package, not this module)";
  m.attr("__version__") = fluxcal::version();
  pybind11::register_exception<fluxcal::Error>(m, "Error", PyExc_ValueError);
  fluxcal_py::bind_ellipsoid(m);
  fluxcal_py::bind_twostep(m);
  fluxcal_py::bind_refine(m);
  fluxcal_py::bind_positions(m);
  fluxcal_py::bind_cable(m);
  fluxcal_py::bind_timeseries(m);
  fluxcal_py::bind_planar(m);
}
