// Bindings of twostep.hpp.
#include "bindings.hpp"

#include <fluxcal/twostep.hpp>

using namespace pybind11::literals;

namespace fluxcal_py {
namespace {

// The Calibration, and the second step's parameter statistics when they were computed (keys as refine's).
py::dict result_dict(const fluxcal::TwoStepResult& r) {
  py::dict d = calibration_dict(r.calibration, r.summary);
  if (!r.parameter_names.empty()) add_parameter_statistics(d, r);
  return d;
}

}  // namespace

void bind_twostep(py::module_& m) {
  using fluxcal::TwoStep2DOptions;
  using fluxcal::TwoStepOptions;
  py::class_<TwoStep2DOptions>(m, "TwoStep2DOptions")
      .def(py::init<>())
      .def_readwrite("refine", &TwoStep2DOptions::refine)
      .def_readwrite("max_iterations", &TwoStep2DOptions::max_iterations)
      .def_readwrite("tolerance", &TwoStep2DOptions::tolerance)
      .def_readwrite("noise_bias_correction", &TwoStep2DOptions::noise_bias_correction)
      .def_readwrite("units", &TwoStep2DOptions::units)
      .def_readwrite("misfit_spread", &TwoStep2DOptions::misfit_spread)
      .def_readwrite("poorly_determined", &TwoStep2DOptions::poorly_determined)
      .def_readwrite("runaway_factor", &TwoStep2DOptions::runaway_factor);

  py::class_<TwoStepOptions>(m, "TwoStepOptions")
      .def(py::init<>())
      .def_readwrite("field_norm", &TwoStepOptions::field_norm)
      .def_readwrite("max_iterations", &TwoStepOptions::max_iterations)
      .def_readwrite("tolerance", &TwoStepOptions::tolerance)
      .def_readwrite("noise_sigma", &TwoStepOptions::noise_sigma)
      .def_readwrite("units", &TwoStepOptions::units)
      .def_readwrite("planar_ratio", &TwoStepOptions::planar_ratio)
      .def_readwrite("poor_coverage_ratio", &TwoStepOptions::poor_coverage_ratio)
      .def_readwrite("poor_direction_coverage", &TwoStepOptions::poor_direction_coverage)
      .def_readwrite("coverage_rows", &TwoStepOptions::coverage_rows)
      .def_readwrite("runaway_misfit", &TwoStepOptions::runaway_misfit)
      .def_readwrite("standard_errors", &TwoStepOptions::standard_errors)
      .def_readwrite("determined_tolerance", &TwoStepOptions::determined_tolerance)
      .def_readwrite("serial_correlation", &TwoStepOptions::serial_correlation)
      .def_readwrite("serial_correlation_alpha", &TwoStepOptions::serial_correlation_alpha);

  // readings arrive as a C-contiguous float64 (N, 2) array and field_norms as float64 (N,) (the Python
  // layer ensures it): no copy.
  m.def(
      "twostep_2d",
      [](const fluxcal::Readings2DRef::Base& readings, const Eigen::Ref<const Eigen::VectorXd>& field_norms,
         const TwoStep2DOptions& options) {
        fluxcal::TwoStep2DResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::twostep_2d(readings, field_norms, options);
        }
        return py::dict("offset"_a = r.offset, "gain"_a = r.gain, "constant_field"_a = r.constant_field,
                        "offset_se"_a = r.offset_se, "gain_se"_a = r.gain_se, "covariance"_a = r.covariance,
                        "units"_a = r.units,
                        "summary"_a = summary_dict(r.summary));
      },
      "readings"_a.noconvert(), "field_norms"_a.noconvert(), "options"_a);

  m.def(
      "twostep",
      [](const fluxcal::SamplesView& samples, const TwoStepOptions& options) {
        fluxcal::TwoStepResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::twostep(samples, options);
        }
        return result_dict(r);
      },
      "samples"_a.noconvert(), "options"_a);
  m.def(
      "twostep_norms",
      [](const fluxcal::SamplesView& samples, const Eigen::VectorXd& field_norms, const TwoStepOptions& options) {
        fluxcal::TwoStepResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::twostep(samples, field_norms, options);
        }
        return result_dict(r);
      },
      "samples"_a.noconvert(), "field_norms"_a, "options"_a);
}

}  // namespace fluxcal_py
