// Bindings of timeseries.hpp, kalman.hpp, fixed_kalman.hpp, drift.hpp and foct.hpp (seed 001).
#include "bindings.hpp"

#include <fluxcal/drift.hpp>
#include <fluxcal/fixed_kalman.hpp>
#include <fluxcal/foct.hpp>  // section "foct.hpp" below
#include <fluxcal/kalman.hpp>
#include <fluxcal/timeseries.hpp>

#include <pybind11/numpy.h>

#include <algorithm>
#include <optional>

using namespace pybind11::literals;

namespace fluxcal_py {
namespace {

/// Largest AR order of the fixed-point filter reachable from Python.
constexpr int kFixedMaxOrder = 16;

py::dict ljung_dict(const fluxcal::LjungBoxResult& r) {
  return py::dict("lags"_a = r.lags, "model_df"_a = r.model_df, "statistic"_a = r.statistic,
                  "p_value"_a = r.p_value, "white"_a = r.white);
}

py::dict segment_dict(const fluxcal::DriftSegment& s) {
  return py::dict("range"_a = std::vector<double>{s.lo, s.hi}, "order"_a = s.order,
                  "coefficients"_a = std::vector<double>(s.coefficients.data(), s.coefficients.data() + s.coefficients.size()),
                  "samples"_a = s.samples, "sse"_a = s.sse, "residual_rms"_a = s.residual_rms,
                  "condition_number"_a = s.condition_number, "f_statistics"_a = s.f_statistics,
                  "x_range"_a = std::vector<double>{s.x_lo, s.x_hi}, "covariance"_a = s.covariance,
                  "standard_errors"_a = s.standard_errors);
}

fluxcal::DriftModel model_from(const std::vector<std::pair<std::pair<double, double>, std::vector<double>>>& segs) {
  fluxcal::DriftModel m;
  for (const auto& s : segs) {
    fluxcal::DriftSegment d;
    d.lo = s.first.first;
    d.hi = s.first.second;
    d.coefficients = Eigen::Map<const Eigen::VectorXd>(s.second.data(), static_cast<Eigen::Index>(s.second.size()));
    d.order = static_cast<int>(s.second.size()) - 1;
    m.segments.push_back(d);
  }
  return m;
}

}  // namespace

// ==== foct.hpp: seed 001 end to end (fit_foct and its helpers) =====================================
// Kept in this file with the other seed-001 bindings (python/CMakeLists.txt lists the binding sources).
namespace {

py::dict reverse_arrangement_dict(const fluxcal::ReverseArrangementResult& t) {
  return py::dict("subseries"_a = t.subseries, "arrangements"_a = t.arrangements, "expected"_a = t.expected,
                  "variance"_a = t.variance, "u"_a = t.u, "stationary"_a = t.stationary, "means"_a = t.means);
}

/// The keys of fluxcal.drift.accuracy.
py::dict accuracy_dict(const fluxcal::AccuracyResult& a) {
  py::list points;
  for (const auto& p : a.points)
    points.append(py::dict("percent_rated"_a = p.percent_rated, "ratio_error_percent"_a = p.ratio_error_percent,
                           "limit_percent"_a = p.limit_percent, "met"_a = p.met));
  return py::dict("class"_a = a.accuracy_class, "rated"_a = a.rated, "max_abs_residual"_a = a.max_abs_residual,
                  "points"_a = points, "met"_a = a.met);
}

py::object accuracy_or_none(const std::optional<fluxcal::AccuracyResult>& a) {
  return a ? py::object(accuracy_dict(*a)) : py::object(py::none());
}

py::dict foct_dict(const fluxcal::FoctResult& r) {
  py::list segs;
  for (const auto& s : r.drift.segments) segs.append(segment_dict(s));
  const auto& pre = r.preprocess;
  const auto& ar = r.ar;
  return py::dict(
      "segments"_a = segs, "noise_ar"_a = r.drift.noise_ar, "drift_summary"_a = summary_dict(r.drift.summary),
      "regressor"_a = r.regressor == fluxcal::DriftRegressor::temperature ? "temp" : "difference",
      "drift_input"_a = r.drift_input == fluxcal::DriftInput::zero_bias ? "zero_bias" : "filtered",
      "orders"_a = r.orders,
      "preprocess"_a = py::dict("mean"_a = pre.mean, "differences"_a = pre.differences,
                                "stationarity"_a = reverse_arrangement_dict(pre.stationarity),
                                "stationarity_after"_a = reverse_arrangement_dict(pre.stationarity_after),
                                "normality"_a = py::dict("skewness"_a = pre.normality.skewness,
                                                         "kurtosis"_a = pre.normality.kurtosis,
                                                         "jarque_bera"_a = pre.normality.jarque_bera,
                                                         "p_value"_a = pre.normality.p_value,
                                                         "normal"_a = pre.normality.normal),
                                "summary"_a = summary_dict(pre.summary)),
      "ar"_a = py::dict("order"_a = ar.order, "coefficients"_a = ar.coefficients, "sigma2"_a = ar.sigma2,
                        "aic"_a = ar.aic, "order_at_maximum"_a = ar.order_at_maximum,
                        "whiteness"_a = ljung_dict(ar.whiteness), "summary"_a = summary_dict(ar.summary)),
      // None without a filter (white noise about the drift), as fit_pipeline's settings["kalman"].
      "kalman"_a = r.kalman_filter ? py::object(py::dict("q"_a = r.q, "r"_a = r.r, "steady_state"_a = r.steady_state))
                                   : py::object(py::none()),
      "notes"_a = r.notes,
      "filtered"_a = r.filtered, "compensated"_a = r.compensated, "residual"_a = r.residual,
      "drift_span_before"_a = r.drift_span_before, "drift_span_after"_a = r.drift_span_after,
      "drift_reduction"_a = r.drift_reduction, "accuracy"_a = accuracy_or_none(r.accuracy),
      "accuracy_drift"_a = accuracy_or_none(r.accuracy_drift), "warnings"_a = r.summary.warnings,
      "summary"_a = summary_dict(r.summary));
}

void bind_foct(py::module_& m) {
  using SeriesRef = fluxcal::SeriesRef::Base;  // what NumPy maps to; the core's checked SeriesRef wraps it
  py::class_<fluxcal::PreprocessOptions>(m, "PreprocessOptions")
      .def(py::init<>())
      .def_readwrite("subseries", &fluxcal::PreprocessOptions::subseries)
      .def_readwrite("threshold", &fluxcal::PreprocessOptions::threshold)
      .def_readwrite("trend_degree", &fluxcal::PreprocessOptions::trend_degree)
      .def_readwrite("significance", &fluxcal::PreprocessOptions::significance)
      .def_readwrite("breaks", &fluxcal::PreprocessOptions::breaks);
  py::enum_<fluxcal::DriftRegressor>(m, "DriftRegressor")
      .value("temp", fluxcal::DriftRegressor::temperature)
      .value("difference", fluxcal::DriftRegressor::difference);
  py::enum_<fluxcal::DriftInput>(m, "DriftInput")
      .value("zero_bias", fluxcal::DriftInput::zero_bias)
      .value("filtered", fluxcal::DriftInput::filtered);
  // Nested options are returned by reference: options.drift.max_order = 3 changes options.
  py::class_<fluxcal::FoctOptions>(m, "FoctOptions")
      .def(py::init<>())
      .def_readwrite("preprocess", &fluxcal::FoctOptions::preprocess)
      .def_readwrite("ar", &fluxcal::FoctOptions::ar)
      .def_readwrite("q", &fluxcal::FoctOptions::q)
      .def_readwrite("r", &fluxcal::FoctOptions::r)
      .def_readwrite("kalman", &fluxcal::FoctOptions::kalman)
      .def_readwrite("regressor", &fluxcal::FoctOptions::regressor)
      .def_readwrite("drift_input", &fluxcal::FoctOptions::drift_input)
      .def_readwrite("drift", &fluxcal::FoctOptions::drift)
      .def_readwrite("level_step", &fluxcal::FoctOptions::level_step)
      .def_readwrite("rated", &fluxcal::FoctOptions::rated)
      .def_readwrite("accuracy_class", &fluxcal::FoctOptions::accuracy_class)
      .def_readwrite("breaks", &fluxcal::FoctOptions::breaks);
  // temp_outside is copied (optional of a Ref would dangle after a dtype conversion).
  m.def("fit_foct", [](const SeriesRef& zero_bias, const SeriesRef& temp,
                       const std::optional<Eigen::VectorXd>& temp_outside, const fluxcal::FoctOptions& options) {
    fluxcal::FoctResult r;
    {
      py::gil_scoped_release release;
      if (temp_outside) {
        const fluxcal::SeriesRef outside(*temp_outside);
        r = fluxcal::fit_foct(zero_bias, temp, &outside, options);
      } else {
        r = fluxcal::fit_foct(zero_bias, temp, nullptr, options);
      }
    }
    return foct_dict(r);
  }, "zero_bias"_a.noconvert(), "temp"_a.noconvert(), "temp_outside"_a = py::none(),
     "options"_a = fluxcal::FoctOptions());
  m.def("foct_compensate", [](const std::vector<std::pair<std::pair<double, double>, std::vector<double>>>& segments,
                              fluxcal::DriftRegressor regressor, const SeriesRef& zero_bias, const SeriesRef& temp,
                              const std::optional<Eigen::VectorXd>& temp_outside) {
    const fluxcal::DriftModel model = model_from(segments);
    if (!temp_outside) return fluxcal::compensate_zero_bias(model, regressor, zero_bias, temp);
    const fluxcal::SeriesRef outside(*temp_outside);
    return fluxcal::compensate_zero_bias(model, regressor, zero_bias, temp, &outside);
  }, "segments"_a, "regressor"_a, "zero_bias"_a.noconvert(), "temp"_a.noconvert(), "temp_outside"_a = py::none());
  m.def("foct_level_means", [](const SeriesRef& values, const SeriesRef& temp, double step) {
    py::dict out;
    for (const auto& l : fluxcal::level_means(values, temp, step)) out[py::float_(l.level)] = l.mean;
    return out;
  }, "values"_a.noconvert(), "temp"_a.noconvert(), "step"_a = 5.0);
  m.def("foct_drift_span", [](const SeriesRef& values, const SeriesRef& temp, double step) {
    return fluxcal::drift_span(values, temp, step);
  }, "values"_a.noconvert(), "temp"_a.noconvert(), "step"_a = 5.0);
  m.def("play", [](const SeriesRef& x, const Eigen::VectorXd& half_widths, const std::string& name) {
    return fluxcal::play(x, half_widths, name);
  }, "x"_a.noconvert(), "half_widths"_a, "name"_a = "x");
  m.def("kalman_dc_gain", [](const Eigen::VectorXd& a, double q, double r, const fluxcal::KalmanOptions& options) {
    return fluxcal::kalman_dc_gain(fluxcal::ArKalman(a, q, r, options));
  }, "a"_a, "q"_a, "r"_a, "options"_a);
  m.def("zero_bias_accuracy", [](const SeriesRef& residual, double rated, const std::string& accuracy_class) {
    return accuracy_dict(fluxcal::zero_bias_accuracy(residual, rated, accuracy_class));
  }, "residual"_a.noconvert(), "rated"_a, "accuracy_class"_a = "0.2S");
}

}  // namespace
// ==== end of the foct.hpp section ====================================================================

void bind_timeseries(py::module_& m) {
  using SeriesRef = fluxcal::SeriesRef::Base;  // what NumPy maps to; the core's checked SeriesRef wraps it
  m.def("ts_zero_mean", [](const SeriesRef& x) {
    double mean = 0.0;
    Eigen::VectorXd z = fluxcal::zero_mean(x, &mean);
    return py::make_tuple(z, mean);
  }, "x"_a.noconvert());
  m.def("ts_difference", [](const SeriesRef& x, int order) { return fluxcal::difference(x, order); },
        "x"_a.noconvert(), "order"_a);
  m.def("ts_remove_trend", [](const SeriesRef& x, int degree) { return fluxcal::remove_trend(x, degree); },
        "x"_a.noconvert(), "degree"_a);
  m.def("ts_reverse_arrangement", [](const SeriesRef& x, int subseries, double threshold) {
    const auto r = fluxcal::reverse_arrangement(x, subseries, threshold);
    return py::dict("subseries"_a = r.subseries, "arrangements"_a = r.arrangements, "expected"_a = r.expected,
                    "variance"_a = r.variance, "u"_a = r.u, "stationary"_a = r.stationary, "means"_a = r.means);
  }, "x"_a.noconvert(), "subseries"_a, "threshold"_a);
  m.def("ts_normality", [](const SeriesRef& x, double significance) {
    const auto r = fluxcal::normality(x, significance);
    return py::dict("skewness"_a = r.skewness, "kurtosis"_a = r.kurtosis, "jarque_bera"_a = r.jarque_bera,
                    "p_value"_a = r.p_value, "normal"_a = r.normal);
  }, "x"_a.noconvert(), "significance"_a);
  m.def("ts_ljung_box", [](const SeriesRef& x, int lags, int model_df, double significance,
                           const fluxcal::Breaks& breaks) {
    return ljung_dict(fluxcal::ljung_box(x, lags, model_df, significance, breaks));
  }, "x"_a.noconvert(), "lags"_a, "model_df"_a, "significance"_a, "breaks"_a = fluxcal::Breaks());
  m.def("ts_preprocess", [](const SeriesRef& x, int subseries, double threshold, int trend_degree,
                            double significance, const fluxcal::Breaks& breaks) {
    fluxcal::PreprocessOptions options;
    options.subseries = subseries;
    options.threshold = threshold;
    options.trend_degree = trend_degree;
    options.significance = significance;
    options.breaks = breaks;
    const auto r = fluxcal::preprocess(x, options);
    auto ra = [](const fluxcal::ReverseArrangementResult& t) {
      return py::dict("subseries"_a = t.subseries, "arrangements"_a = t.arrangements, "expected"_a = t.expected,
                      "variance"_a = t.variance, "u"_a = t.u, "stationary"_a = t.stationary, "means"_a = t.means);
    };
    return py::dict("mean"_a = r.mean, "series"_a = r.series, "differences"_a = r.differences,
                    "stationarity"_a = ra(r.stationarity), "stationarity_after"_a = ra(r.stationarity_after),
                    "normality"_a = py::dict("skewness"_a = r.normality.skewness, "kurtosis"_a = r.normality.kurtosis,
                                             "jarque_bera"_a = r.normality.jarque_bera,
                                             "p_value"_a = r.normality.p_value, "normal"_a = r.normality.normal),
                    "summary"_a = summary_dict(r.summary));
  }, "x"_a.noconvert(), "subseries"_a, "threshold"_a, "trend_degree"_a, "significance"_a,
     "breaks"_a = fluxcal::Breaks());
  m.def("ts_chi2_sf", &fluxcal::chi2_sf, "x"_a, "df"_a);
  m.def("ts_f1_sf", &fluxcal::f1_sf, "x"_a, "df"_a);

  py::class_<fluxcal::ArOptions>(m, "ArOptions")
      .def(py::init<>())
      .def_readwrite("max_order", &fluxcal::ArOptions::max_order)
      .def_readwrite("order", &fluxcal::ArOptions::order)
      .def_readwrite("init_samples", &fluxcal::ArOptions::init_samples)
      .def_readwrite("forgetting", &fluxcal::ArOptions::forgetting)
      .def_readwrite("whiteness_lags", &fluxcal::ArOptions::whiteness_lags)
      .def_readwrite("significance", &fluxcal::ArOptions::significance)
      .def_readwrite("breaks", &fluxcal::ArOptions::breaks);
  m.def("fit_ar", [](const SeriesRef& y, const fluxcal::ArOptions& options) {
    fluxcal::ArResult r;
    {
      py::gil_scoped_release release;
      r = fluxcal::fit_ar(y, options);
    }
    return py::dict("order"_a = r.order, "coefficients"_a = r.coefficients, "sigma2"_a = r.sigma2,
                    "covariance"_a = r.covariance, "standard_errors"_a = r.standard_errors, "aic"_a = r.aic,
                    "order_at_maximum"_a = r.order_at_maximum, "residuals"_a = r.residuals,
                    "whiteness"_a = ljung_dict(r.whiteness), "summary"_a = summary_dict(r.summary));
  }, "y"_a.noconvert(), "options"_a);

  py::class_<fluxcal::KalmanOptions>(m, "KalmanOptions")
      .def(py::init<>())
      .def_readwrite("initial_variance", &fluxcal::KalmanOptions::initial_variance)
      .def_readwrite("steady_state", &fluxcal::KalmanOptions::steady_state)
      .def_readwrite("riccati_max_iterations", &fluxcal::KalmanOptions::riccati_max_iterations)
      .def_readwrite("riccati_tolerance", &fluxcal::KalmanOptions::riccati_tolerance);
  m.def("kalman_setup", [](const Eigen::VectorXd& a, double q, double r, const fluxcal::KalmanOptions& options) {
    const fluxcal::ArKalman k(a, q, r, options);
    Eigen::MatrixXd prior;
    int iterations = 0;
    const Eigen::VectorXd gain = k.steady_state_gain(&prior, &iterations);
    return py::dict("initial_covariance"_a = k.initial_covariance(), "steady_gain"_a = gain,
                    "steady_prior_covariance"_a = prior, "riccati_iterations"_a = iterations,
                    "spectral_radius"_a = k.spectral_radius());
  }, "a"_a, "q"_a, "r"_a, "options"_a);
  m.def("kalman_filter", [](const Eigen::VectorXd& a, double q, double r, const fluxcal::KalmanOptions& options,
                            const SeriesRef& y, const fluxcal::Breaks& breaks) {
    fluxcal::KalmanResult res;
    {
      py::gil_scoped_release release;
      res = fluxcal::ArKalman(a, q, r, options).filter(y, breaks);
    }
    return py::dict("filtered"_a = res.filtered, "innovations"_a = res.innovations, "state"_a = res.state,
                    "covariance"_a = res.covariance, "gain"_a = res.gain, "summary"_a = summary_dict(res.summary));
  }, "a"_a, "q"_a, "r"_a, "options"_a, "y"_a.noconvert(), "breaks"_a = fluxcal::Breaks());
  m.def("kalman_noise_from_ar", [](int order, const Eigen::VectorXd& coefficients, double sigma2, double r) {
    fluxcal::ArResult fit;
    fit.order = order;
    fit.coefficients = coefficients;
    fit.sigma2 = sigma2;
    const auto k = fluxcal::ArKalman::from_ar(fit, r);
    return py::make_tuple(k.coefficients(), k.q(), k.r());
  }, "order"_a, "coefficients"_a, "sigma2"_a, "r"_a);
  m.def("ar_stationary_covariance", &fluxcal::ar_stationary_covariance, "a"_a, "q"_a);

  m.attr("FIXED_MAX_ORDER") = kFixedMaxOrder;
  m.attr("DRIFT_EDGE_MARGIN") = fluxcal::kDriftEdgeMargin;
  m.def("fixed_kalman_filter",
        [](const std::vector<std::int32_t>& a, const std::vector<std::int32_t>& gain, std::int32_t q, std::int32_t r,
           const std::vector<std::int32_t>& p0, int signal_frac_bits, int coef_frac_bits, int cov_frac_bits,
           bool steady_state, const py::array_t<std::int32_t, py::array::c_style | py::array::forcecast>& y,
           long checkpoint_every, const fluxcal::Breaks& breaks) {
          using Filter = fluxcal::FixedArKalman<kFixedMaxOrder>;
          const int n = static_cast<int>(a.size());
          if (n < 1 || n > kFixedMaxOrder)
            throw fluxcal::Error("ar_coeffs: order " + std::to_string(n) + " outside 1 … " +
                                 std::to_string(kFixedMaxOrder) + " (the fixed-point filter's MaxOrder)");
          if (gain.size() != a.size() || p0.size() != a.size() * a.size())
            throw fluxcal::Error("fixed_kalman_filter: gain/p0 sizes do not match the order");
          Filter::Coefficients c;
          c.order = n;
          c.format = {signal_frac_bits, coef_frac_bits, cov_frac_bits};
          c.steady_state = steady_state;
          c.q = q;
          c.r = r;
          for (int i = 0; i < n; ++i) {
            c.a[i] = a[i];
            c.gain[i] = gain[i];
          }
          std::copy(p0.begin(), p0.end(), c.p0);  // the struct takes the exported layout (stride n)
          Filter f;
          if (!f.configure(c)) throw fluxcal::Error("fixed_kalman_filter: coef_frac_bits must be within 0 … 30");
          fluxcal::check_breaks(breaks, static_cast<Eigen::Index>(y.size()), "breaks");
          py::array_t<std::int32_t> out(y.size());
          // Optional checkpoints: the filter's full state (x, K, P) before every checkpoint_every-th sample.
          const long len = static_cast<long>(y.size());
          const long chunks = checkpoint_every > 0 ? (len + checkpoint_every - 1) / checkpoint_every : 0;
          py::array_t<std::int32_t> cx({chunks, static_cast<long>(n)}), ck({chunks, static_cast<long>(n)}),
              cp({chunks, static_cast<long>(n * n)});
          {
            py::gil_scoped_release release;
            auto x = cx.mutable_unchecked<2>();
            auto kk = ck.mutable_unchecked<2>();
            auto pp = cp.mutable_unchecked<2>();
            std::int32_t* o = out.mutable_data();
            const std::int32_t* in = y.data();
            std::size_t next_break = 0;
            for (long i = 0; i < len; ++i) {
              if (next_break < breaks.size() && i == breaks[next_break]) {  // a gap in time: as firmware would
                f.reset();
                ++next_break;
              }
              if (checkpoint_every > 0 && i % checkpoint_every == 0) {
                const long c = i / checkpoint_every;
                for (int a_i = 0; a_i < n; ++a_i) {
                  x(c, a_i) = f.state()[a_i];
                  kk(c, a_i) = f.gain()[a_i];
                  for (int j = 0; j < n; ++j) pp(c, a_i * n + j) = f.covariance(a_i, j);
                }
              }
              o[i] = f.step(in[i]);
            }
          }
          std::vector<std::int32_t> state(f.state(), f.state() + n), k(f.gain(), f.gain() + n), p(n * n);
          for (int i = 0; i < n; ++i)
            for (int j = 0; j < n; ++j) p[i * n + j] = f.covariance(i, j);
          return py::dict("output"_a = out, "overflowed"_a = f.overflowed(), "state"_a = state, "gain"_a = k,
                          "covariance"_a = p, "checkpoint_state"_a = cx, "checkpoint_gain"_a = ck,
                          "checkpoint_covariance"_a = cp);
        },
        "a"_a, "gain"_a, "q"_a, "r"_a, "p0"_a, "signal_frac_bits"_a, "coef_frac_bits"_a, "cov_frac_bits"_a,
        "steady_state"_a, "y"_a, "checkpoint_every"_a = 0, "breaks"_a = fluxcal::Breaks());

  py::class_<fluxcal::DriftOptions>(m, "DriftOptions")
      .def(py::init<>())
      .def_readwrite("breakpoints", &fluxcal::DriftOptions::breakpoints)
      .def_readwrite("max_order", &fluxcal::DriftOptions::max_order)
      .def_readwrite("significance", &fluxcal::DriftOptions::significance)
      .def_readwrite("order", &fluxcal::DriftOptions::order)
      .def_readwrite("continuous", &fluxcal::DriftOptions::continuous)
      .def_readwrite("min_samples", &fluxcal::DriftOptions::min_samples)
      .def_readwrite("whiten", &fluxcal::DriftOptions::whiten)
      .def_readwrite("whiten_max_order", &fluxcal::DriftOptions::whiten_max_order)
      .def_readwrite("breaks", &fluxcal::DriftOptions::breaks);
  m.def("fit_drift", [](const SeriesRef& select, const SeriesRef& x, const SeriesRef& w,
                        const fluxcal::DriftOptions& options) {
    fluxcal::DriftModel model;
    {
      py::gil_scoped_release release;
      model = fluxcal::fit_drift(select, x, w, options);
    }
    py::list segs;
    for (const auto& s : model.segments) segs.append(segment_dict(s));
    return py::dict("segments"_a = segs, "noise_ar"_a = model.noise_ar, "summary"_a = summary_dict(model.summary),
                    "range_note"_a = model.range_note);
  }, "select"_a.noconvert(), "x"_a.noconvert(), "w"_a.noconvert(), "options"_a);
  m.def("drift_evaluate", [](const std::vector<std::pair<std::pair<double, double>, std::vector<double>>>& segments,
                             const SeriesRef& select, const SeriesRef& x) {
    return model_from(segments).evaluate(select, x);
  }, "segments"_a, "select"_a.noconvert(), "x"_a.noconvert());
  m.def("drift_standard_error", [](const std::vector<std::pair<std::pair<double, double>, std::vector<double>>>& segments,
                                   const std::vector<Eigen::MatrixXd>& covariances, const SeriesRef& select,
                                   const SeriesRef& x) {
    fluxcal::DriftModel model = model_from(segments);
    if (covariances.size() != model.segments.size())
      throw fluxcal::Error("drift: " + std::to_string(covariances.size()) + " covariances for " +
                           std::to_string(model.segments.size()) + " segments");
    for (std::size_t s = 0; s < covariances.size(); ++s) model.segments[s].covariance = covariances[s];
    return model.standard_error(select, x);
  }, "segments"_a, "covariances"_a, "select"_a.noconvert(), "x"_a.noconvert());
  bind_foct(m);  // the foct.hpp section above
}

}  // namespace fluxcal_py
