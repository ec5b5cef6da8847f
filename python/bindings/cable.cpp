// Bindings of cable.hpp.
#include "bindings.hpp"

#include <fluxcal/cable.hpp>

using namespace pybind11::literals;

namespace fluxcal_py {
namespace {

fluxcal::CableRing make_ring(const Eigen::VectorXd& angles, double radius, const Eigen::VectorXd& axis_angles,
                             double bore_radius) {
  fluxcal::CableRing r;
  r.angles = angles;
  r.radius = radius;
  r.axis_angles = axis_angles;
  r.bore_radius = bore_radius;
  return r;
}

}  // namespace

void bind_cable(py::module_& m) {
  using fluxcal::CableSolveOptions;
  py::enum_<CableSolveOptions::Refiner>(m, "CableRefiner")
      .value("automatic", CableSolveOptions::Refiner::automatic)
      .value("ceres", CableSolveOptions::Refiner::ceres)
      .value("dense", CableSolveOptions::Refiner::dense);
  py::class_<CableSolveOptions>(m, "CableSolveOptions")
      .def(py::init<>())
      .def_readwrite("n_conductors", &CableSolveOptions::n_conductors)
      .def_readwrite("zero_sum_currents", &CableSolveOptions::zero_sum_currents)
      .def_readwrite("grid_points", &CableSolveOptions::grid_points)
      .def_readwrite("starts", &CableSolveOptions::starts)
      .def_readwrite("max_iterations", &CableSolveOptions::max_iterations)
      .def_readwrite("function_tolerance", &CableSolveOptions::function_tolerance)
      .def_readwrite("gradient_tolerance", &CableSolveOptions::gradient_tolerance)
      .def_readwrite("parameter_tolerance", &CableSolveOptions::parameter_tolerance)
      .def_readwrite("dogleg", &CableSolveOptions::dogleg)
      .def_readwrite("refiner", &CableSolveOptions::refiner)
      .def_readwrite("noise_sigma", &CableSolveOptions::noise_sigma)
      .def_readwrite("max_position_sigma", &CableSolveOptions::max_position_sigma)
      .def_readwrite("max_current_relative_sigma", &CableSolveOptions::max_current_relative_sigma)
      .def_readwrite("misfit_ratio", &CableSolveOptions::misfit_ratio)
      .def_readwrite("noise_sigma_dof", &CableSolveOptions::noise_sigma_dof)
      .def_readwrite("misfit_alpha", &CableSolveOptions::misfit_alpha)
      .def_readwrite("relative_sigma", &CableSolveOptions::relative_sigma)
      .def_readwrite("fit_background", &CableSolveOptions::fit_background)
      .def_readwrite("initial_positions", &CableSolveOptions::initial_positions)
      .def_readwrite("initial_currents", &CableSolveOptions::initial_currents);

  m.def(
      "cable_field",
      [](const Eigen::VectorXd& angles, double radius, const Eigen::VectorXd& axis_angles, double bore_radius,
         const fluxcal::ConductorPositions& positions, const Eigen::VectorXd& currents) {
        return fluxcal::cable_field(make_ring(angles, radius, axis_angles, bore_radius), positions, currents);
      },
      "angles"_a, "radius"_a, "axis_angles"_a, "bore_radius"_a, "positions"_a, "currents"_a);

  m.def(
      "cable_field_jacobian",
      [](const Eigen::VectorXd& angles, double radius, const Eigen::VectorXd& axis_angles, double bore_radius,
         const fluxcal::ConductorPositions& positions, const Eigen::VectorXd& currents) {
        return fluxcal::cable_field_jacobian(make_ring(angles, radius, axis_angles, bore_radius), positions, currents);
      },
      "angles"_a, "radius"_a, "axis_angles"_a, "bore_radius"_a, "positions"_a, "currents"_a);

  m.def(
      "solve_cable",
      [](const Eigen::VectorXd& angles, double radius, const Eigen::VectorXd& axis_angles, double bore_radius,
         const Eigen::MatrixXd& readings, const CableSolveOptions& options) {
        fluxcal::CableSolution r;
        const fluxcal::CableRing ring = make_ring(angles, radius, axis_angles, bore_radius);
        {
          py::gil_scoped_release release;
          r = fluxcal::solve_cable(ring, readings, options);
        }
        return py::dict("positions"_a = r.positions, "currents"_a = r.currents,
                        "background"_a = options.fit_background ? py::object(py::cast(Eigen::Vector2d(r.background))) : py::none(),
                        "covariance"_a = r.covariance,
                        "standard_errors"_a = r.standard_errors, "well_conditioned"_a = r.well_conditioned, "fits_model"_a = r.fits_model,
                        "misfit_p"_a = r.misfit_p,
                        "noise_sigma"_a = r.noise_sigma, "fisher_condition"_a = r.fisher_condition,
                        "residuals"_a = r.residuals, "starts_tried"_a = r.starts_tried,
                        "summary"_a = summary_dict(r.summary));
      },
      "angles"_a, "radius"_a, "axis_angles"_a, "bore_radius"_a, "readings"_a, "options"_a);
}

}  // namespace fluxcal_py
