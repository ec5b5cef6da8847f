// Calibrates a three-axis magnetometer with the installed fluxcal library.
//   calibrate_example              fits a built-in simulated recording and checks the result
//   calibrate_example FILE [NORM]  fits the first three numeric columns of FILE (CSV or whitespace);
//                                  NORM: the field magnitude (0: the fitted radius)
#include <fluxcal/ellipsoid.hpp>
#include <fluxcal/version.hpp>

#include <cmath>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace {

fluxcal::Samples read_rows(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw fluxcal::Error(path + ": cannot open");
  std::vector<double> values;
  std::string line;
  while (std::getline(in, line)) {
    for (char& ch : line)
      if (ch == ',' || ch == ';' || ch == '\t') ch = ' ';
    std::istringstream fields(line);
    double v[3];
    if (fields >> v[0] >> v[1] >> v[2]) values.insert(values.end(), v, v + 3);  // headers skip
  }
  fluxcal::Samples s(static_cast<Eigen::Index>(values.size() / 3), 3);
  for (Eigen::Index i = 0; i < s.rows(); ++i)
    for (int j = 0; j < 3; ++j) s(i, j) = values[static_cast<std::size_t>(3 * i + j)];
  return s;
}

fluxcal::Samples simulate(const Eigen::Matrix3d& W, const Eigen::Vector3d& b, double field, int n) {
  std::mt19937 rng(7);
  std::normal_distribution<double> gauss(0.0, 1.0);
  fluxcal::Samples s(n, 3);
  for (int i = 0; i < n; ++i) {
    Eigen::Vector3d dir(gauss(rng), gauss(rng), gauss(rng));
    const Eigen::Vector3d noise(gauss(rng), gauss(rng), gauss(rng));
    s.row(i) = (W * (field * dir.normalized()) + b + 0.002 * field * noise).transpose();
  }
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    std::cout << "fluxcal " << fluxcal::version() << " (headers " FLUXCAL_VERSION_STRING ")\n";
    fluxcal::EllipsoidOptions options;
    fluxcal::Samples samples;
    Eigen::Matrix3d W;
    W << 1.10, 0.05, -0.02, 0.05, 0.92, 0.03, -0.02, 0.03, 1.04;
    const Eigen::Vector3d b(120.0, -40.0, 75.0);
    const bool simulated = argc < 2;
    if (simulated) {
      options.field_norm = 500.0;
      samples = simulate(W, b, options.field_norm, 2000);
    } else {
      samples = read_rows(argv[1]);
      if (argc > 2) {
        const std::string arg = argv[2];
        std::size_t used = 0;
        try {
          options.field_norm = std::stod(arg, &used);
        } catch (const std::exception&) {  // std::invalid_argument, std::out_of_range
          used = 0;
        }
        if (used == 0 || used != arg.size()) {  // the range (≥ 0, finite) is fit_ellipsoid's to check
          std::cerr << "usage: calibrate_example [FILE [NORM]]\nerror: NORM must be a number, got '"
                    << arg << "'\n";
          return 2;
        }
      }
    }
    const fluxcal::EllipsoidResult r = fluxcal::fit_ellipsoid(samples, options);
    const Eigen::IOFormat fmt(6, 0, ", ", "\n", "  [", "]");
    std::cout << r.summary.message << "\noffset b:\n" << r.calibration.offset.transpose().format(fmt)
              << "\nmatrix A:\n" << r.calibration.matrix.format(fmt) << "\n";
    for (const auto& w : r.summary.warnings) std::cout << "warning: " << w << "\n";
    if (simulated) {  // the symmetric A of a symmetric W is W⁻¹ exactly
      const double eb = (r.calibration.offset - b).norm() / options.field_norm;
      const double ea = (r.calibration.matrix - W.inverse()).norm() / W.inverse().norm();
      std::cout << "offset error " << 100 * eb << " % of field, matrix error " << 100 * ea << " %\n";
      if (eb > 0.01 || ea > 0.01) {
        std::cerr << "FAIL: simulated calibration not recovered\n";
        return 1;
      }
      std::cout << "OK\n";
    }
    return 0;
  } catch (const fluxcal::Error& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 2;
  }
}
