// Shared by the binding files of fluxcal._core: conversion helpers and one bind_* per capability.
#pragma once

#include <fluxcal/types.hpp>

#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace fluxcal_py {

namespace py = pybind11;

/// A Summary as a plain dict (what Calibration.summary holds and JSON stores).
py::dict summary_dict(const fluxcal::Summary& s);
/// What a fit's residuals said about correlation in time (SerialCorrelationReport) as a plain dict.
py::dict serial_correlation_dict(const fluxcal::SerialCorrelationReport& r);
/// A Calibration plus its Summary as the dict fluxcal's Python layer turns into a Calibration.
py::dict calibration_dict(const fluxcal::Calibration& c, const fluxcal::Summary& s);

/// A fit's parameter statistics (RefineResult, TwoStepResult) added to its result dict under refine's keys; without
/// a covariance (TWOSTEP's exact fit of 9 readings) the verdict alone: no covariance, standard_errors or
/// serial_correlation keys.
template <class Result>
void add_parameter_statistics(py::dict& d, const Result& r) {
  d["parameters"] = r.parameters;
  d["parameter_names"] = r.parameter_names;
  d["determined"] = r.determined;
  d["identifiable"] = r.identifiable;
  if (r.covariance.size() == 0) return;
  d["covariance"] = r.covariance;
  d["standard_errors"] = r.standard_errors;
  d["serial_correlation"] = serial_correlation_dict(r.serial_correlation);
}

void bind_ellipsoid(py::module_& m);  // ellipsoid.cpp (also coverage)
void bind_twostep(py::module_& m);    // twostep.cpp
void bind_refine(py::module_& m);     // refine.cpp (also fit_vector)
void bind_positions(py::module_& m);  // positions.cpp (multi-position, accelerometer)
void bind_cable(py::module_& m);      // cable.cpp
void bind_timeseries(py::module_& m); // timeseries.cpp (also kalman, fixed_kalman, drift, foct)
void bind_planar(py::module_& m);     // planar.cpp

}  // namespace fluxcal_py
