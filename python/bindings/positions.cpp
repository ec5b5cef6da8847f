// Bindings of positions.hpp (multi-position calibration, accelerometer calibration) and alignment.hpp (the
// magnetometer turned onto the accelerometer).
#include "bindings.hpp"

#include <fluxcal/alignment.hpp>
#include <fluxcal/positions.hpp>

using namespace pybind11::literals;

namespace fluxcal_py {
namespace {

using Rotations = Eigen::Matrix<double, Eigen::Dynamic, 9, Eigen::RowMajor>;  // N rotations, each row-major

std::vector<Eigen::Matrix3d> to_rotations(const Rotations& rows) {
  std::vector<Eigen::Matrix3d> out;
  for (Eigen::Index i = 0; i < rows.rows(); ++i) {
    Eigen::Matrix3d R;
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) R(j, k) = rows(i, 3 * j + k);
    out.push_back(R);
  }
  return out;
}

Rotations from_rotations(const std::vector<Eigen::Matrix3d>& rs) {
  Rotations out(static_cast<Eigen::Index>(rs.size()), 9);
  for (std::size_t i = 0; i < rs.size(); ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) out(static_cast<Eigen::Index>(i), 3 * j + k) = rs[i](j, k);
  return out;
}

py::dict result_dict(const fluxcal::PositionsResult& r) {
  return py::dict("offset"_a = r.offset, "K"_a = r.K, "field"_a = r.field, "yaw"_a = r.yaw,
                  "rotations"_a = from_rotations(r.rotations), "reference"_a = r.reference,
                  "residuals"_a = r.residuals, "parameter_names"_a = r.parameter_names,
                  "parameters"_a = r.parameters, "standard_errors"_a = r.standard_errors,
                  "determined"_a = r.determined, "noise_sigma"_a = r.noise_sigma,
                  "noise_dof"_a = r.noise_dof, "units"_a = r.units,
                  "summary"_a = summary_dict(r.summary));
}

}  // namespace

void bind_positions(py::module_& m) {
  using fluxcal::PositionsOptions;
  py::enum_<fluxcal::Frame>(m, "Frame").value("ned", fluxcal::Frame::ned).value("nue", fluxcal::Frame::nue);
  py::class_<PositionsOptions>(m, "PositionsOptions")
      .def(py::init<>())
      .def_readwrite("frame", &PositionsOptions::frame)
      .def_readwrite("estimate_yaw", &PositionsOptions::estimate_yaw)
      .def_readwrite("estimate_inclination", &PositionsOptions::estimate_inclination)
      .def_readwrite("tilt_sigma_deg", &PositionsOptions::tilt_sigma_deg)
      .def_readwrite("output_sigma", &PositionsOptions::output_sigma)
      .def_readwrite("gravity", &PositionsOptions::gravity)
      .def_readwrite("gravity_tolerance", &PositionsOptions::gravity_tolerance)
      .def_readwrite("max_iterations", &PositionsOptions::max_iterations)
      .def_readwrite("determined_tolerance", &PositionsOptions::determined_tolerance)
      .def_readwrite("units", &PositionsOptions::units);

  m.def("local_up", &fluxcal::local_up, "frame"_a);
  m.def("pitch_roll", &fluxcal::pitch_roll, "specific_force"_a, "frame"_a);
  m.def("body_to_local", &fluxcal::body_to_local, "pitch"_a, "roll"_a, "yaw"_a, "frame"_a);
  m.def("heading_rotation", &fluxcal::heading_rotation, "angle"_a, "frame"_a);
  m.def("level_rotation", &fluxcal::level_rotation, "nominal"_a, "body_up"_a, "frame"_a);
  m.def("twelve_positions", [](fluxcal::Frame f) { return from_rotations(fluxcal::twelve_positions(f)); }, "frame"_a);
  m.def(
      "fit_positions",
      [](const fluxcal::SamplesView& outputs, const fluxcal::SamplesView& reference, const PositionsOptions& o) {
        fluxcal::PositionsResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::fit_positions(outputs, reference, o);
        }
        return result_dict(r);
      },
      "outputs"_a.noconvert(), "reference"_a.noconvert(), "options"_a);
  m.def(
      "calibrate_positions",
      [](const fluxcal::SamplesView& outputs, const fluxcal::SamplesView& specific_force, const Rotations& nominal,
         const Eigen::Vector3d& field, const PositionsOptions& o) {
        const auto rots = to_rotations(nominal);
        fluxcal::PositionsResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::calibrate_positions(outputs, specific_force, rots, field, o);
        }
        return result_dict(r);
      },
      "outputs"_a.noconvert(), "specific_force"_a.noconvert(), "nominal"_a, "field"_a, "options"_a);
  m.def(
      "twelve_position_closed_form",
      [](const fluxcal::SamplesView& outputs, double field_up) {
        const auto c = fluxcal::twelve_position_closed_form(outputs, field_up);
        return py::dict("offset"_a = c.offset, "K"_a = c.K);
      },
      "outputs"_a.noconvert(), "field_up"_a);
  m.def(
      "calibrate_accelerometer",
      [](const fluxcal::SamplesView& readings, double gravity, int max_iterations) {
        fluxcal::AccelerometerOptions o;
        o.gravity = gravity;
        o.max_iterations = max_iterations;
        fluxcal::AccelerometerResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::calibrate_accelerometer(readings, o);
        }
        return py::dict("offset"_a = r.offset, "matrix"_a = r.matrix, "gravity"_a = r.gravity,
                        "misalignment_estimated"_a = r.misalignment_estimated,
                        "magnitude_errors"_a = r.magnitude_errors, "tilt_error_deg"_a = r.tilt_error_deg,
                        "summary"_a = summary_dict(r.summary));
      },
      "readings"_a.noconvert(), "gravity"_a, "max_iterations"_a);

  py::class_<fluxcal::AlignmentOptions>(m, "AlignmentOptions")
      .def(py::init<>())
      .def_readwrite("max_dynamic", &fluxcal::AlignmentOptions::max_dynamic)
      .def_readwrite("max_iterations", &fluxcal::AlignmentOptions::max_iterations)
      .def_readwrite("tolerance", &fluxcal::AlignmentOptions::tolerance)
      .def_readwrite("max_se_deg", &fluxcal::AlignmentOptions::max_se_deg)
      .def_readwrite("noise_bias_correction", &fluxcal::AlignmentOptions::noise_bias_correction)
      .def_readwrite("serial_correlation", &fluxcal::AlignmentOptions::serial_correlation)
      .def_readwrite("serial_correlation_alpha", &fluxcal::AlignmentOptions::serial_correlation_alpha);
  m.def(
      "align_to_gravity",
      [](const fluxcal::SamplesView& field, const fluxcal::SamplesView& specific_force,
         const fluxcal::AlignmentOptions& options) {
        fluxcal::AlignmentResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::align_to_gravity(field, specific_force, options);
        }
        return py::dict("rotation"_a = r.rotation, "rotation_vector"_a = r.rotation_vector, "dip"_a = r.dip,
                        "covariance"_a = r.covariance, "standard_errors"_a = r.standard_errors,
                        "residual_rms"_a = r.residual_rms, "readings_used"_a = r.readings_used,
                        "residuals"_a = r.residuals, "serial_correlation"_a = serial_correlation_dict(r.serial_correlation),
                        "identifiable"_a = r.identifiable, "summary"_a = summary_dict(r.summary));
      },
      "field"_a.noconvert(), "specific_force"_a.noconvert(), "options"_a);
}

}  // namespace fluxcal_py
