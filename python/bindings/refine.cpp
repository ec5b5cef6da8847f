// Bindings of refine.hpp.
#include "bindings.hpp"

#include <fluxcal/refine.hpp>

#include <optional>

using namespace pybind11::literals;

namespace fluxcal_py {
namespace {

py::dict result_dict(const fluxcal::RefineResult& r) {
  py::dict d = calibration_dict(r.calibration, r.summary);
  add_parameter_statistics(d, r);
  d["noise_sigma"] = r.noise_sigma;
  d["fisher_condition"] = r.fisher_condition;
  d["solver_report"] = r.solver_report;
  d["residuals"] = r.residuals;
  d["jacobian"] = r.jacobian;
  return d;
}

fluxcal::Calibration make_calibration(const Eigen::Vector3d& offset, const Eigen::Matrix3d& matrix, double field_norm,
                                      const std::string& units) {
  fluxcal::Calibration c;
  c.offset = offset;
  c.matrix = matrix;
  c.field_norm = field_norm;
  c.units = units;
  return c;
}

}  // namespace

void bind_refine(py::module_& m) {
  using fluxcal::RefineOptions;
  py::enum_<fluxcal::Loss>(m, "Loss")
      .value("none", fluxcal::Loss::none)
      .value("huber", fluxcal::Loss::huber)
      .value("cauchy", fluxcal::Loss::cauchy);
  py::enum_<fluxcal::SerialCorrelation>(m, "SerialCorrelation")
      .value("automatic", fluxcal::SerialCorrelation::automatic)
      .value("independent", fluxcal::SerialCorrelation::independent)
      .value("newey_west", fluxcal::SerialCorrelation::newey_west);
  py::enum_<fluxcal::Shape>(m, "Shape")
      .value("sphere", fluxcal::Shape::sphere)
      .value("diagonal", fluxcal::Shape::diagonal)
      .value("symmetric", fluxcal::Shape::symmetric);
  py::class_<RefineOptions>(m, "RefineOptions")
      .def(py::init<>())
      .def_readwrite("loss", &RefineOptions::loss)
      .def_readwrite("shape", &RefineOptions::shape)
      .def_readwrite("loss_scale", &RefineOptions::loss_scale)
      .def_readwrite("max_iterations", &RefineOptions::max_iterations)
      .def_readwrite("function_tolerance", &RefineOptions::function_tolerance)
      .def_readwrite("gradient_tolerance", &RefineOptions::gradient_tolerance)
      .def_readwrite("parameter_tolerance", &RefineOptions::parameter_tolerance)
      .def_readwrite("determined_tolerance", &RefineOptions::determined_tolerance)
      .def_readwrite("units", &RefineOptions::units)
      .def_readwrite("noise_bias_correction", &RefineOptions::noise_bias_correction)
      .def_readwrite("serial_correlation", &RefineOptions::serial_correlation)
      .def_readwrite("serial_correlation_alpha", &RefineOptions::serial_correlation_alpha);

  m.def(
      "refine",
      [](const Eigen::Vector3d& offset, const Eigen::Matrix3d& matrix, double field_norm, const std::string& units,
         const fluxcal::SamplesView& samples, const RefineOptions& options) {
        fluxcal::RefineResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::refine(make_calibration(offset, matrix, field_norm, units), samples, options);
        }
        return result_dict(r);
      },
      "offset"_a, "matrix"_a, "field_norm"_a, "units"_a, "samples"_a.noconvert(), "options"_a);
  m.def(
      "refine_norms",
      [](const Eigen::Vector3d& offset, const Eigen::Matrix3d& matrix, double field_norm, const std::string& units,
         const fluxcal::SamplesView& samples, const Eigen::VectorXd& field_norms, const RefineOptions& options) {
        fluxcal::RefineResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::refine(make_calibration(offset, matrix, field_norm, units), samples, field_norms, options);
        }
        return result_dict(r);
      },
      "offset"_a, "matrix"_a, "field_norm"_a, "units"_a, "samples"_a.noconvert(), "field_norms"_a, "options"_a);
  m.def(
      "refine_vector",
      [](const Eigen::Vector3d& offset, const Eigen::Matrix3d& matrix, double field_norm, const std::string& units,
         const fluxcal::SamplesView& samples, const fluxcal::SamplesView& reference, const RefineOptions& options) {
        fluxcal::RefineResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::refine_vector(make_calibration(offset, matrix, field_norm, units), samples, reference,
                                     options);
        }
        return result_dict(r);
      },
      "offset"_a, "matrix"_a, "field_norm"_a, "units"_a, "samples"_a.noconvert(), "reference"_a.noconvert(),
      "options"_a);
  m.def(
      "fit_vector",
      [](const fluxcal::SamplesView& samples, const fluxcal::SamplesView& reference, const RefineOptions& options) {
        fluxcal::RefineResult r;
        {
          py::gil_scoped_release release;
          r = fluxcal::fit_vector(samples, reference, options);
        }
        return result_dict(r);
      },
      "samples"_a.noconvert(), "reference"_a.noconvert(), "options"_a);
  m.def(
      "refine_terms",
      [](const Eigen::Vector3d& offset, const Eigen::Matrix3d& matrix, double field_norm, const std::string& units,
         const fluxcal::SamplesView& samples, const Eigen::Ref<const Eigen::MatrixXd>& features,
         const Eigen::VectorXd& start_terms, const std::vector<std::string>& fixed, const RefineOptions& options,
         std::optional<fluxcal::SamplesView> reference, std::optional<Eigen::VectorXd> field_norms) {
        if (reference && field_norms)
          throw fluxcal::Error("field_norms: the vector model takes its field from the reference vectors; give one "
                               "or the other");
        fluxcal::RefineResult r;
        {
          py::gil_scoped_release release;
          const auto start = make_calibration(offset, matrix, field_norm, units);
          const std::optional<fluxcal::SamplesRef> checked = reference ? std::optional<fluxcal::SamplesRef>(*reference)
                                                                      : std::nullopt;
          r = field_norms ? fluxcal::refine_terms(start, samples, *field_norms, features, start_terms, fixed, options)
                          : fluxcal::refine_terms(start, samples, features, start_terms, fixed, options,
                                                  checked ? &*checked : nullptr);
        }
        return result_dict(r);
      },
      "offset"_a, "matrix"_a, "field_norm"_a, "units"_a, "samples"_a.noconvert(), "features"_a, "start_terms"_a,
      "fixed"_a, "options"_a, "reference"_a = py::none(), "field_norms"_a = py::none());
}

}  // namespace fluxcal_py
