"""fluxcal export-c: the generated C header compiles (C99, -Wall -Werror; and as C++), its float and
fixed-point corrections reproduce Calibration.apply on the generated test vector within the stated
precision (float: relative 1e-6; fixed: the stated bound, and bit for bit with the Python model), the
self-test catches a damaged constant, and the Kalman part runs bit-exactly in fixed_kalman.hpp."""
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

import fluxcal
from conftest import REPO, run_cli, simulated
from fluxcal import drift, sim
from fluxcal.export_c import (FLOAT_RELATIVE_TOLERANCE, QFormat, export_c, fixed_point, load_kalman,
                              reading_extent, save_kalman)
from fluxcal.kalman import FixedArKalman

# Prints, per test vector, the float input and output (9 digits: exact for float) and the fixed output,
# then the header's own self-test result.
DRIVER = r"""
#include <stdio.h>
#include "HEADER"
int main(void) {
  int k;
  for (k = 0; k < P_TEST_COUNT; ++k) {
    float hf[3];
    int32_t hq[3];
    int saturated;
    p_apply_float(p_test_input_f[k], hf);
    saturated = p_apply_fixed(p_test_input_q[k], hq);
    printf("%.9g %.9g %.9g %.9g %.9g %.9g %ld %ld %ld %d\n", p_test_input_f[k][0], p_test_input_f[k][1],
           p_test_input_f[k][2], hf[0], hf[1], hf[2], (long)hq[0], (long)hq[1], (long)hq[2], saturated);
  }
  printf("self_test %d\n", p_self_test());
  return 0;
}
"""


def compiler(c_plus_plus=False):
    found = shutil.which("c++" if c_plus_plus else "cc") or shutil.which("g++" if c_plus_plus else "gcc")
    if found is None:
        pytest.fail("no C/C++ compiler on PATH (the build needs one anyway)")
    return found


def run_driver(tmp_path, header, c_plus_plus=False):
    """Compile the driver against `header` (prefix p) and return (rows as an array, self-test result)."""
    source = tmp_path / ("driver.cpp" if c_plus_plus else "driver.c")
    source.write_text(DRIVER.replace("HEADER", header.name))
    exe = tmp_path / ("driver_cpp" if c_plus_plus else "driver_c")
    flags = ["-std=c++17"] if c_plus_plus else ["-std=c99"]
    build = subprocess.run([compiler(c_plus_plus), *flags, "-Wall", "-Wextra", "-Werror", "-O2", f"-I{header.parent}",
                            str(source), "-o", str(exe)], capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.splitlines()
    rows = np.array([[float(v) for v in line.split()] for line in out[:-1]])
    return rows, int(out[-1].split()[1])


def calibrations():
    s = simulated(11, n=1500)  # nT, soft iron ±20 %, offset up to half the field
    nt = fluxcal.calibrate(s.readings, field_norm=s.field_norm, units="nT")
    gauss = fluxcal.calibrate(simulated(12, n=1500, field_norm=0.47).readings, units="Gauss")
    return {"nT": nt, "Gauss": gauss}


CALS = calibrations()


@pytest.mark.parametrize("which, q_format", [("nT", None), ("nT", "Q22.9"), ("Gauss", None), ("Gauss", "Q4.27")])
def test_header_reproduces_calibration_apply(tmp_path, which, q_format):
    cal = CALS[which]
    header = tmp_path / "magcal.h"
    result = export_c(cal, header, q_format=q_format, name="p")
    fx = result.fixed
    rows, self_test = run_driver(tmp_path, header)
    assert self_test == 0
    inputs_f, h_float, h_fixed, saturated = rows[:, :3], rows[:, 3:6], rows[:, 6:9], rows[:, 9]
    assert len(rows) == len(result.inputs_q) == 30
    assert not saturated.any()
    # float: relative 1e-6 of the result (of the field norm when the result is small)
    expected_f = cal.apply(inputs_f)
    scale = np.maximum(np.abs(expected_f).max(axis=1, keepdims=True), cal.field_norm)
    float_error = np.abs(h_float - expected_f) / scale
    assert float_error.max() <= FLOAT_RELATIVE_TOLERANCE
    # fixed: within the stated bound of the double result for the exact values the inputs stand for
    exact = cal.apply(result.inputs_q * fx.fmt.lsb)
    fixed_error = np.abs(h_fixed * fx.out_fmt.lsb - exact)
    assert fixed_error.max() <= fx.error_bound
    assert fixed_error.max() > 0.05 * fx.error_bound  # the bound is not vacuous (measured 0.1–0.4 of it)
    # and bit for bit what the Python model of the firmware arithmetic says
    model, model_saturated = fx.apply_int(result.inputs_q)
    np.testing.assert_array_equal(h_fixed, model)
    assert not model_saturated
    if q_format is not None:
        assert str(fx.fmt) == q_format
    header_text = header.read_text()
    assert f"Signal format {fx.fmt}" in header_text and f"#define P_Q_FRAC_BITS {fx.fmt.frac_bits}" in header_text


@pytest.mark.parametrize("field_units, field_norm", [("uT", 48.0), ("T", 4.8e-5)])
def test_counts_with_a_large_offset_to_any_unit_keep_the_fields_precision(tmp_path, field_units, field_norm):
    """int16 counts at 6 counts/µT with a hard iron of 20000 counts: one float of b lost |b| 2^-24, and the header's
    own self-test failed 30 components of this correct calibration (a blind check); corrected to tesla, h shared the
    readings' Q16.15 and its LSB was 30 µT against a 48 µT field. Now b is two floats and h has its own format: the
    self-test passes, and the fixed output is within a thousandth of the field of the double result."""
    w = np.array([[6.1, 0.2, -0.1], [0.2, 5.8, 0.15], [-0.1, 0.15, 6.3]]) * (48.0 / field_norm)  # counts per unit
    cal = fluxcal.Calibration(offset=np.array([20000.0, -15000.0, 18000.0]), matrix=np.linalg.inv(w),
                              field_norm=field_norm, units="counts")
    cal.field_units = field_units
    header = tmp_path / "lg.h"
    result = export_c(cal, header, name="p", input_range=32768)
    fx = result.fixed
    rows, self_test = run_driver(tmp_path, header)
    assert self_test == 0
    assert fx.error_bound < 1e-3 * field_norm and fx.out_fmt != fx.fmt, (fx.error_bound, fx.out_fmt)
    exact = cal.apply(result.inputs_q * fx.fmt.lsb)
    assert np.abs(rows[:, 6:9] * fx.out_fmt.lsb - exact).max() <= fx.error_bound
    text = header.read_text()
    assert f"#define P_H_Q_FRAC_BITS {fx.out_fmt.frac_bits}" in text and f"Output format {fx.out_fmt} for h" in text


def test_default_format_follows_the_range_rule():
    cal = CALS["nT"]
    fx = fixed_point(cal)
    extent = reading_extent(cal)
    assert fx.input_range == pytest.approx(2 * extent, rel=1e-6)
    # the smallest m that holds the range and every output for it: one integer bit fewer would not
    outputs = np.abs(cal.matrix) @ (fx.input_range + np.abs(cal.offset))
    assert outputs.max() + fx.error_bound <= fx.out_fmt.max_value
    assert outputs.max() + fx.error_bound > QFormat(fx.out_fmt.int_bits - 1, fx.out_fmt.frac_bits + 1).max_value
    smaller = QFormat(fx.fmt.int_bits - 1, fx.fmt.frac_bits + 1)
    assert fx.input_range + np.abs(cal.offset).max() > smaller.max_value
    # a format with too few integer bits for the field is refused with the smallest that works
    with pytest.raises(ValueError, match=r"--q-format Q10.21: readings of the calibration field reach .* use at least Q1[5-7]\.1[4-6]"):
        fixed_point(cal, "Q10.21")
    # a tight format keeps the range it can hold (between 1 and 2 extents), and says so
    tight = fixed_point(cal, f"Q{fx.fmt.int_bits - 1}.{fx.fmt.frac_bits + 1}")
    assert extent <= tight.input_range < 2 * extent and "holds no more" in tight.range_note


def test_self_test_catches_a_damaged_constant(tmp_path):
    header = tmp_path / "magcal.h"
    export_c(CALS["nT"], header, name="p")
    text = header.read_text()
    start = text.index("p_matrix_q[3][3] = {\n  {") + len("p_matrix_q[3][3] = {\n  {")
    end = text.index(",", start)
    damaged = int(text[start:end]) + 4096  # a matrix entry off by 2^12 units of 2^-na
    header.write_text(text[:start] + str(damaged) + text[end:])
    _, self_test = run_driver(tmp_path, header)
    assert self_test > 0


def test_header_is_valid_cplusplus(tmp_path):
    header = tmp_path / "magcal.h"
    export_c(CALS["Gauss"], header, name="p")
    rows, self_test = run_driver(tmp_path, header, c_plus_plus=True)
    assert self_test == 0 and len(rows) == 30


def test_q_format_parsing():
    assert QFormat.parse("Q12.19") == QFormat(12, 19) and str(QFormat.parse(" q1.30 ")) == "Q1.30"
    with pytest.raises(ValueError, match="m \\+ n must be 31"):
        QFormat.parse("Q3.3")
    with pytest.raises(ValueError, match="is not Qm.n"):
        QFormat.parse("16.15")


# -- Kalman coefficients ----------------------------------------------------------------------------------------

KALMAN_DRIVER = r"""
#include <cstdio>
#include <fluxcal/fixed_kalman.hpp>
#include "HEADER"
int main() {
  constexpr int N = P_KALMAN_ORDER;
  fluxcal::FixedArKalmanCoefficients<N> c;
  c.order = N;
  c.format = {P_KALMAN_SIGNAL_FRAC_BITS, P_KALMAN_COEF_FRAC_BITS, P_KALMAN_COV_FRAC_BITS};
  c.steady_state = P_KALMAN_STEADY_STATE;
  c.q = p_kalman_q; c.r = p_kalman_r;
  for (int i = 0; i < N; ++i) { c.a[i] = p_kalman_a[i]; c.gain[i] = p_kalman_gain[i]; }
  for (int i = 0; i < N * N; ++i) c.p0[i] = p_kalman_p0[i];
  fluxcal::FixedArKalman<N> f;
  if (!f.configure(c)) return 2;
  int mismatches = 0;
  for (int k = 0; k < P_KALMAN_TEST_COUNT; ++k) {
    const std::int32_t out = f.step(p_kalman_test_input[k]);
    mismatches += out != p_kalman_test_output[k];
    std::printf("%d\n", out);
  }
  std::printf("mismatches %d\n", mismatches);
  return f.overflowed() ? 3 : 0;
}
"""


def run_kalman_driver(tmp_path, header):
    source = tmp_path / "kalman.cpp"
    source.write_text(KALMAN_DRIVER.replace("HEADER", header.name))
    exe = tmp_path / "kalman"
    build = subprocess.run([compiler(True), "-std=c++17", "-Wall", "-Werror", "-O1", f"-I{REPO / 'cpp' / 'include'}",
                            f"-I{header.parent}", str(source), "-o", str(exe)], capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    run = subprocess.run([str(exe)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.split("\n")
    return np.array([int(v) for v in lines[:-2]]), int(lines[-2].split()[1])


KALMAN_C_DRIVER = r"""
#include <stdio.h>
#include "HEADER"
int main(void) {
  p_kalman_t f;
  int k;
  p_kalman_reset(&f);
  for (k = 0; k < P_KALMAN_TEST_COUNT; ++k) printf("%ld\n", (long)p_kalman_step(&f, p_kalman_test_input[k]));
  printf("overflow %d\n", f.overflow);
  printf("self_test %d\n", p_kalman_self_test());
  return 0;
}
"""


def run_kalman_c_driver(tmp_path, header, c_plus_plus=False):
    """The header's own C filter, compiled as C99 (pedantic) or C++: (outputs, overflow flag, self-test)."""
    source = tmp_path / ("kalman_c.cpp" if c_plus_plus else "kalman_c.c")
    source.write_text(KALMAN_C_DRIVER.replace("HEADER", header.name))
    exe = tmp_path / ("kalman_c_cpp" if c_plus_plus else "kalman_c")
    flags = ["-std=c++17"] if c_plus_plus else ["-std=c99", "-pedantic"]
    build = subprocess.run([compiler(c_plus_plus), *flags, "-Wall", "-Wextra", "-Werror", "-O2", f"-I{header.parent}",
                            str(source), "-o", str(exe)], capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    lines = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.split("\n")
    return np.array([int(v) for v in lines[:-3]]), int(lines[-3].split()[1]), int(lines[-2].split()[1])


@pytest.mark.parametrize("steady_state", [False, True])
def test_kalman_coefficients_run_bit_exact_in_the_firmware_filter(tmp_path, steady_state):
    f = FixedArKalman((0.6, -0.3, 0.2), 0.5, 0.3, frac_bits=28, steady_state=steady_state)
    saved = save_kalman(f, tmp_path / "kf.json")
    assert load_kalman(saved).coefficients() == f.coefficients()
    header = tmp_path / "p.h"
    r = run_cli("export-c", CALS["nT"].save(tmp_path / "cal.json"), "-o", header, "--name", "p", "--kalman", saved)
    assert r.returncode == 0, r.stderr
    assert "AR(3) Kalman filter in C99" in r.stdout
    outputs, mismatches = run_kalman_driver(tmp_path, header)
    assert mismatches == 0
    text = header.read_text()
    y_int = np.array([int(v) for v in text.split("p_kalman_test_input[256] = {")[1].split("}")[0].split(",")])
    np.testing.assert_array_equal(outputs, FixedArKalman((0.6, -0.3, 0.2), 0.5, 0.3, frac_bits=28,
                                                         steady_state=steady_state).filter_int(y_int))
    assert np.abs(y_int).max() > 2 ** 24  # the test signal uses the format's range, not a few LSB
    _, self_test = run_driver(tmp_path, header)  # the calibration part is still C99 with the Kalman part in
    assert self_test == 0
    for c_plus_plus in (False, True):  # the header's own filter, for firmware in C: the same bits
        c_outputs, overflow, kalman_self_test = run_kalman_c_driver(tmp_path, header, c_plus_plus)
        np.testing.assert_array_equal(c_outputs, outputs)
        assert overflow == 0 and kalman_self_test == 0


def test_the_c_filter_reports_saturation_and_its_self_test_catches_a_damaged_constant(tmp_path):
    f = FixedArKalman((0.6, -0.3, 0.2), 0.5, 0.3, frac_bits=28)
    header = tmp_path / "p.h"
    export_c(CALS["nT"], header, name="p", kalman=f)
    text = header.read_text()
    # inputs at the rails saturate the state: the flag is set and outputs clamp as FixedArKalman's do
    driver = KALMAN_C_DRIVER.replace("p_kalman_test_input[k]", "(k % 2 ? INT32_MAX : INT32_MIN)")
    (tmp_path / "rail.c").write_text(driver.replace("HEADER", header.name))
    exe = tmp_path / "rail"
    subprocess.run([compiler(), "-std=c99", "-Wall", "-Werror", f"-I{tmp_path}", str(tmp_path / "rail.c"), "-o",
                    str(exe)], check=True)
    lines = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.split("\n")
    expected = FixedArKalman((0.6, -0.3, 0.2), 0.5, 0.3, frac_bits=28)
    rails = np.where(np.arange(256) % 2 == 1, 2 ** 31 - 1, -(2 ** 31))
    np.testing.assert_array_equal([int(v) for v in lines[:-3]], expected.filter_int(rails))
    assert expected.overflowed and lines[-3] == "overflow 1"
    # a damaged AR coefficient: the header's self-test fails
    a = text.split("p_kalman_a[3] = {")[1].split(",")[0]
    header.write_text(text.replace(f"p_kalman_a[3] = {{{a},", f"p_kalman_a[3] = {{{int(a) + 1000},", 1))
    _, _, self_test = run_kalman_c_driver(tmp_path, header)
    assert self_test > 0


def test_headers_are_plain_ascii_and_name_no_reserved_identifier(tmp_path, monkeypatch):
    """The FOCT header carried a '±' (a blind check): tool chains that read sources as Latin-1 or refuse bytes
    above 127 choke on it. Every header is ASCII now: fluxcal's own symbols spelled out (never the '?' of an
    unknown one), a user's µ as u, and a fullwidth '＊／' in a unit, which NFKD turns into '*/', still cannot end the
    comment. A --name starting with '_' made reserved file-scope names (C99 7.1.3) and was accepted."""
    import unicodedata

    import fluxcal.export_c as ec

    fallbacks, real = [], ec._ascii

    def spy(text):  # the characters _ascii can only write as '?'
        fallbacks.extend(ch for ch in text if not ch.isascii() and ch not in ec._ASCII_SPELLING
                         and not unicodedata.normalize("NFKD", ch).encode("ascii", "ignore"))
        return real(text)

    monkeypatch.setattr(ec, "_ascii", spy)
    foct = sim.foct_zero_bias(rng=np.random.default_rng(1), hold_s=300, ramp_s=150)
    model, _ = drift.fit_pipeline(foct.columns["zero_bias"], foct.columns["temp"])
    saved = model.save(tmp_path / "drift.json")
    ec.export_c(None, tmp_path / "foct.h", name="p", kalman=saved, drift=saved)
    ec.export_c(CALS["nT"], tmp_path / "cal.h", name="p", kalman=saved)
    assert fallbacks == []
    monkeypatch.setattr(ec, "_ascii", real)
    for header in (tmp_path / "foct.h", tmp_path / "cal.h"):
        text = header.read_bytes()
        assert max(text) < 128 and b"+/-" in text, header
    tricky = fluxcal.Calibration.from_dict({**CALS["nT"].to_dict(), "units": "µT＊／ int evil; ／＊"})
    header = tmp_path / "p.h"
    ec.export_c(tricky, header, name="p")
    code = re.sub(r"/\*.*?\*/", "", header.read_text(encoding="ascii"), flags=re.S)
    assert "evil" not in code and "uT" in header.read_text()
    assert run_driver(tmp_path, header)[1] == 0
    for name in ("_x", "__x", "_Bool"):
        with pytest.raises(ValueError, match=f"--name: '{name}' starts with '_': C reserves"):
            ec.export_c(CALS["nT"], tmp_path / "r.h", name=name)
    assert ec.default_name("_mag.h") == "cal_mag" and ec.default_name("magnétomètre.h") == "magn_tom_tre"


def test_kalman_from_a_drift_model(tmp_path):
    foct = sim.foct_zero_bias(rng=np.random.default_rng(1), hold_s=300, ramp_s=150)
    model, _ = drift.fit_pipeline(foct.columns["zero_bias"], foct.columns["temp"])
    path = model.save(tmp_path / "drift.json")
    f = load_kalman(path)
    data = json.loads(path.read_text())
    np.testing.assert_allclose(f.double.ar_coeffs, data["ar"]["coefficients"])
    assert f.double.q == data["kalman"]["q"] and f.double.r == data["kalman"]["r"]
    sigma = np.sqrt(f.double.initial_covariance[0, 0] + f.double.r)
    need = 2 * 8 * sigma * f.signal_gain  # the stated rule: 2·G·max|y| fits, max|y| = 8 σ
    assert f.signal_gain >= 1 and 2.0 ** (31 - f.frac_bits) >= need > 2.0 ** (30 - f.frac_bits)
    header = tmp_path / "p.h"
    export_c(CALS["nT"], header, name="p", kalman=path)
    outputs, mismatches = run_kalman_driver(tmp_path, header)
    assert mismatches == 0 and len(outputs) == 256


def test_kalman_signal_range_is_stated_and_can_be_widened(tmp_path):
    """The firmware filter's signal format is sized for 8 σ of its input; a 40 σ readout spike saturated it and
    nothing let a user widen it, and --q-format with --kalman alone was taken and ignored (a blind check). The header
    states the reach; --kalman-range widens it (still bit exact); --q-format without a calibration is refused."""
    foct = sim.foct_zero_bias(rng=np.random.default_rng(1), hold_s=300, ramp_s=150)
    model, _ = drift.fit_pipeline(foct.columns["zero_bias"], foct.columns["temp"])
    path = model.save(tmp_path / "drift.json")
    narrow = export_c(None, tmp_path / "n.h", name="n", kalman=path)
    wide = export_c(None, tmp_path / "p.h", name="p", kalman=path, kalman_range=10.0)  # (the driver's prefix)
    reach = [float(re.search(r"inputs to ±([0-9.e+-]+)\)", r.describe()).group(1)) for r in (narrow, wide)]
    assert reach[1] >= 10.0 > reach[0] and wide.kalman.frac_bits < narrow.kalman.frac_bits, reach
    assert "unsaturated" in (tmp_path / "p.h").read_text()
    outputs, mismatches = run_kalman_driver(tmp_path, tmp_path / "p.h")
    assert mismatches == 0 and len(outputs) == 256
    with pytest.raises(ValueError, match="--q-format: .*without a calibration nothing takes it"):
        export_c(None, tmp_path / "q.h", q_format="Q5.26", kalman=path)
    with pytest.raises(ValueError, match="--kalman-range: the largest input of a Kalman filter; give one"):
        export_c(None, tmp_path / "q.h", drift=path, kalman_range=1.0)


def test_a_kalman_range_that_defeats_the_filter_is_said(tmp_path):
    """A --kalman-range in the wrong unit (1e12 for 1) made every output 0, one below the noise saturated 5998 of 6000
    samples; both compiled and passed the self-test (a blind check). Each is warned, in the header too; a range
    the noise sits well inside is not."""
    foct = sim.foct_zero_bias(rng=np.random.default_rng(1), hold_s=300, ramp_s=150)
    model, _ = drift.fit_pipeline(foct.columns["zero_bias"], foct.columns["temp"])
    path = model.save(tmp_path / "drift.json")
    f = load_kalman(path)
    sigma = float(np.sqrt(f.double.initial_covariance[0, 0] + f.double.r))
    coarse = export_c(None, tmp_path / "c.h", name="c", kalman=path, kalman_range=1e8 * sigma)
    assert any("loses that precision" in w for w in coarse.warnings), coarse.warnings
    assert "WARNING: --kalman-range" in (tmp_path / "c.h").read_text()
    narrow = export_c(None, tmp_path / "n.h", name="n", kalman=path, kalman_range=0.1 * sigma)
    assert any("most samples will" in w for w in narrow.warnings), narrow.warnings
    fine = export_c(None, tmp_path / "f.h", name="f", kalman=path, kalman_range=20 * sigma)
    assert not [w for w in fine.warnings if "--kalman-range" in w], fine.warnings
    text = (tmp_path / "f.h").read_text()
    assert "f_kalman_reset() again after a gap in time" in text  # as fluxcal's filter restarts
    # a saved filter's own format is judged alike (frac_bits 40 beside its noise σ had saturated every sample unsaid)
    saved = save_kalman(FixedArKalman(f.double.ar_coeffs, f.double.q, f.double.r, frac_bits=40), tmp_path / "s.json")
    own = export_c(None, tmp_path / "s.h", name="s", kalman=saved)
    assert any("its JSON's): inputs past" in w and "most samples will" in w for w in own.warnings), own.warnings
    assert not export_c(None, tmp_path / "d.h", name="d", kalman=path).warnings  # the default format: 8 σ


def test_text_from_the_files_cannot_end_a_comment_of_the_header(tmp_path):
    """A unit is the user's text: 'counts*/x' ended the header's comment and it failed to compile, and
    '*/ int evil; /*' compiled with a declaration of its own (a blind check). Both stay inside comments now."""
    cal = CALS["nT"]
    for unit in ("counts*/x", "*/ int evil; /*", "n\nT"):
        tricky = fluxcal.Calibration.from_dict({**cal.to_dict(), "units": unit})
        header = tmp_path / "p.h"
        export_c(tricky, header, name="p", source="a*/b.json")
        code = re.sub(r"/\*.*?\*/", "", header.read_text(), flags=re.S)  # what the compiler sees
        assert "evil" not in code and "counts" not in code and "*/" not in code, code[:400]
        rows, self_test = run_driver(tmp_path, header)
        assert self_test == 0


def test_the_bound_for_real_readings_covers_their_rounding_into_the_format():
    """E holds against A (m − b) of the reading in the signal format; a real reading rounded into it adds
    2^-(n+1) Σ|a_ij|, and a blind check measured 1.60 nT against E = 1.26 at Q31.0. The header states E_r for
    that, and it holds."""
    cal = CALS["nT"]
    fx = fixed_point(cal, "Q31.0")
    r = np.random.default_rng(3).uniform(-fx.input_range, fx.input_range, (20000, 3))
    h_q, saturated = fx.apply_int(fx.to_fixed(r))
    error = np.abs(h_q * fx.out_fmt.lsb - cal.apply(r)).max()
    assert not saturated and fx.error_bound < error <= fx.reading_error_bound, (fx.error_bound, error)


def test_kalman_from_a_drift_model_without_a_filter(tmp_path):
    # White noise about the drift (AR order 0): the drift model has no Kalman filter ("kalman": null), and
    # export-c --kalman says so rather than exporting a filter the pipeline did not use.
    foct = sim.foct_zero_bias(rng=np.random.default_rng(2), ar=())
    model, report = drift.fit_pipeline(foct.columns["zero_bias"], foct.columns["temp"])
    assert report["ar"]["order"] == 0
    path = model.save(tmp_path / "drift.json")
    r = run_cli("export-c", CALS["nT"].save(tmp_path / "cal.json"), "-o", tmp_path / "p.h", "--kalman", path)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "no Kalman filter to export: the noise about its drift is white (AR order 0)" in r.stderr, r.stderr
    assert not (tmp_path / "p.h").exists()
    # its drift alone: the header does not speak of a filter the model has not (a blind check)
    export_c(None, tmp_path / "d.h", drift=path)
    text = (tmp_path / "d.h").read_text()
    assert "white (AR order 0): there is no Kalman filter" in text and "Kalman filter (--kalman) runs" not in text


def test_cli_export_c_and_its_errors(tmp_path):
    cal = CALS["nT"].save(tmp_path / "cal.json")
    r = run_cli("export-c", cal, "-o", tmp_path / "sensor-7.h")
    assert r.returncode == 0, r.stderr
    assert "fixed-point error ≤" in r.stdout and "30 test vectors" in r.stdout
    assert "sensor_7_apply_fixed" in (tmp_path / "sensor-7.h").read_text()  # default prefix from the file name
    assert "functions sensor_7_apply_float/_apply_fixed/_self_test(), macros SENSOR_7_*" in r.stdout, r.stdout
    for args, message in [(("--q-format", "Q8.8"), "m + n must be 31"),
                          (("--q-format", "Q3.28"), "use at least Q1"),
                          (("--name", "7up"), "not a C identifier"),
                          (("--kalman", tmp_path / "absent.json"), "absent.json: cannot read")]:
        r = run_cli("export-c", cal, "-o", tmp_path / "x.h", *args)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, r.stderr
    r = run_cli("export-c", tmp_path / "nocal.json", "-o", tmp_path / "x.h")
    assert r.returncode == 2 and "nocal.json" in r.stderr


@pytest.mark.parametrize("scale, frac_bits", [(1e-6, None), (1e12, None), (1.0, -4), (1.0, 40)])
def test_kalman_signal_format_beyond_q0_31(tmp_path, scale, frac_bits):
    # The signal format follows the signal's scale: more than 31 fraction bits for a 1e-6-scale drift model,
    # negative for a 1e12-scale one. The header stays consistent: the firmware filter reproduces the test
    # vector bit for bit and the C99 part still compiles cleanly and passes its self-test.
    a, q, r = (0.6, -0.3, 0.2), 0.5 * scale ** 2, 0.3 * scale ** 2
    f = FixedArKalman(a, q, r, frac_bits=frac_bits)
    saved = save_kalman(f, tmp_path / "kf.json")
    loaded = load_kalman(saved)
    if frac_bits is None:
        sigma = np.sqrt(loaded.double.initial_covariance[0, 0] + r)
        assert loaded.frac_bits == loaded.signal_frac_bits(8 * sigma)
        assert (loaded.frac_bits > 31) if scale < 1 else (loaded.frac_bits < 0)
    else:
        assert loaded.frac_bits == frac_bits
    header = tmp_path / "p.h"
    result = export_c(CALS["nT"], header, name="p", kalman=saved)
    assert f"signal int32 x 2^{-loaded.frac_bits}" in result.describe()
    text = header.read_text()
    bits = str(loaded.frac_bits) if loaded.frac_bits >= 0 else f"({loaded.frac_bits})"
    assert f"#define P_KALMAN_SIGNAL_FRAC_BITS {bits} " in text
    outputs, mismatches = run_kalman_driver(tmp_path, header)
    assert mismatches == 0 and len(outputs) == 256
    y_int = result.kalman_test[0]
    assert np.abs(y_int).max() > 2 ** 24  # the test vector uses the format's range whatever its scale
    _, self_test = run_driver(tmp_path, header)
    assert self_test == 0


def test_export_c_names_a_wrong_kalman(tmp_path):
    import numpy as np

    import fluxcal
    from fluxcal.export_c import export_c

    cal = fluxcal.Calibration(offset=[0, 0, 0], matrix=np.eye(3))
    with pytest.raises(TypeError, match="kalman: expected a FixedArKalman or the path of its JSON, got int"):
        export_c(cal, tmp_path / "o.h", kalman=5)  # AttributeError: 'int' object has no attribute 'frac_bits'
    with pytest.raises(TypeError, match="cal: expected a fluxcal.Calibration"):
        export_c({"offset": [0, 0, 0]}, tmp_path / "o.h")


DRIFT_DRIVER = r"""
#include <stdio.h>
#include "HEADER"
int main(void) {
  double temp, outside, f;
  while (scanf("%lf %lf", &temp, &outside) == 2) {
    const int outside_range = p_drift(temp, outside, &f);
    printf("%d %.17g\n", outside_range, f);
  }
  printf("self_test %d\n", p_drift_self_test());
  return 0;
}
"""


@pytest.mark.parametrize("regressor", ["temp", "difference"])
def test_drift_model_in_c_matches_the_model_and_needs_no_calibration(tmp_path, regressor):
    """A FOCT's firmware gets f(T) per temperature range (and its Kalman filter) without a magnetometer."""
    foct = sim.foct_zero_bias(rng=np.random.default_rng(1), hold_s=300, ramp_s=150, self_heating=3.0)
    outside = foct.columns["temp_outside"] if regressor == "difference" else None
    model, _ = drift.fit_pipeline(foct.columns["zero_bias"], foct.columns["temp"], outside, regressor=regressor)
    saved = model.save(tmp_path / "drift.json")
    header = tmp_path / "p.h"
    r = run_cli("export-c", "-o", header, "--name", "p", "--drift", saved, "--kalman", saved)
    assert r.returncode == 0, r.stderr
    assert f"drift f({'T' if regressor == 'temp' else 'T - T_outside'}) in {len(model.segments)} temperature range" \
        in r.stdout and "Kalman filter in C99" in r.stdout and "magnetometer" not in header.read_text()[:200]
    source = tmp_path / "drift.c"
    source.write_text(DRIFT_DRIVER.replace("HEADER", header.name))
    exe = tmp_path / "drift"
    subprocess.run([compiler(), "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", f"-I{tmp_path}",
                    str(source), "-o", str(exe)], check=True)
    lo, hi = model.segments[0]["range"][0], model.segments[-1]["range"][1]
    margin = drift.EDGE_MARGIN * (hi - lo)  # a later log reads a little beyond the fit's coldest and hottest samples
    temps = np.concatenate([np.random.default_rng(5).uniform(lo, hi, 200), [lo, hi, lo - 0.5 * margin,
                            hi + 0.5 * margin, lo - 2 * margin, hi + 2 * margin]])
    outs = temps - np.random.default_rng(6).uniform(0.0, 10.0, temps.size)
    run = subprocess.run([str(exe)], input="".join(f"{t:.17g} {o:.17g}\n" for t, o in zip(temps, outs)),
                         capture_output=True, text=True, check=True)
    lines = run.stdout.split("\n")
    flags = np.array([int(line.split()[0]) for line in lines[:-2]])
    values = np.array([float(line.split()[1]) for line in lines[:-2]])
    assert lines[-2] == "self_test 0"
    # within the margin as DriftModel.evaluate; beyond it outside every range: said, not extrapolated — and for the
    # difference, beyond what its range saw of it (a blind check's −1.32 A at 20 °C, fitted over −1 … 7 °C)
    expected = model.evaluate(temps, outs if regressor == "difference" else None, outside="nan")
    refused = ~np.isfinite(expected)
    np.testing.assert_array_equal(flags, refused)
    assert refused[-2:].all() and (refused[:204].sum() > 0) == (regressor == "difference"), refused.sum()
    np.testing.assert_allclose(values[~refused], expected[~refused], rtol=1e-12,
                               atol=1e-12 * np.abs(expected[~refused]).max())
    assert np.all(values[refused] == 0.0)
    if regressor == "difference":
        with pytest.raises(ValueError, match=r"temp − temp_outside .* is outside what the model's range .* was fitted "
                                             r"over"):
            model.evaluate(temps, outs)


def test_export_c_needs_something_to_export(tmp_path):
    r = run_cli("export-c", "-o", tmp_path / "p.h")
    assert r.returncode == 2 and "nothing to export" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "p.h").exists()


def test_an_undetermined_calibration_is_refused_unless_forced(tmp_path):
    """A sensor turned about one axis with a few degrees of wobble: calibrate flags it NOT identifiable, and
    firmware must not get it silently (export-c refuses; --force writes it with a warning in the header;
    apply warns)."""
    rng = np.random.default_rng(5)
    rot = sim.sweeps("z", per_turn=600, tilt_deg=4.0, rng=rng)
    result = sim.simulate(rot, [sim.SoftIron(np.diag([1.05, 0.97, 1.02])), sim.HardIron([8.0, -5.0, 20.0]),
                                sim.WhiteNoise(0.05)], np.array([19.6, 0.8, 45.2]), rng)
    src = fluxcal.write_csv(tmp_path / "wobble.csv", {"mx": result.readings[:, 0], "my": result.readings[:, 1],
                                                      "mz": result.readings[:, 2]}, units={k: "uT" for k in "mxyz"})
    run = run_cli("calibrate", src, "-o", tmp_path / "cal.json")
    assert run.returncode == 3 and "identifiable          NO" in run.stdout, run.stdout + run.stderr
    assert "not identifiable (exit status 3)" in run.stderr and (tmp_path / "cal.json").is_file()
    run = run_cli("export-c", tmp_path / "cal.json", "-o", tmp_path / "cal.h")
    assert run.returncode == 2 and "not identifiable" in run.stderr and "--force" in run.stderr
    assert not (tmp_path / "cal.h").exists()
    run = run_cli("export-c", tmp_path / "cal.json", "-o", tmp_path / "cal.h", "--force")
    assert run.returncode == 0, run.stderr
    assert "WARNING (exported with --force): the calibration is not identifiable" in (tmp_path / "cal.h").read_text()
    run = run_cli("apply", tmp_path / "cal.json", src, "-o", tmp_path / "out.csv")
    assert run.returncode == 0 and "warning:" in run.stdout and "not identifiable" in run.stdout
    # a hand-edited flag as a string ("false" is a true string) is refused, not taken for identifiable
    edited = json.loads((tmp_path / "cal.json").read_text())
    edited["summary"]["identifiable"] = "false"
    (tmp_path / "edited.json").write_text(json.dumps(edited))
    run = run_cli("export-c", tmp_path / "edited.json", "-o", tmp_path / "edited.h")
    assert run.returncode == 2 and "summary.identifiable 'false' must be true or false" in run.stderr, run.stderr
    assert not (tmp_path / "edited.h").exists()


RAIL_DRIVER = r"""
#include <stdio.h>
#include "HEADER"
int main(void) {
  const int32_t inputs[4][3] = {{INT32_MAX, 0, 0}, {0, INT32_MIN, 0}, {0, 0, INT32_MAX}, {1000, -1000, 500}};
  int32_t h[3];
  int k;
  for (k = 0; k < 4; ++k) printf("%d\n", p_apply_fixed(inputs[k], h));
  return 0;
}
"""


def test_fixed_point_flags_a_reading_clamped_in_its_conversion(tmp_path):
    """The header tells firmware to saturate readings converting them to Q-format: a reading at INT32_MIN or
    INT32_MAX is such a clamped one, and apply_fixed says so (a blind check's full-scale 16-bit readings came out
    wrong with the flag at 0)."""
    header = tmp_path / "p.h"
    export_c(CALS["nT"], header, name="p")
    (tmp_path / "rail.c").write_text(RAIL_DRIVER.replace("HEADER", header.name))
    exe = tmp_path / "rail"
    subprocess.run([compiler(), "-std=c99", "-Wall", "-Wextra", "-Werror", f"-I{tmp_path}", str(tmp_path / "rail.c"),
                    "-o", str(exe)], check=True)
    flags = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.split()
    assert flags == ["1", "1", "1", "0"]


def test_a_calibration_that_did_not_converge_is_refused_unless_forced(tmp_path):
    """Firmware must not get a solver's intermediate iterate silently (a blind check exported a TWOSTEP whose
    second step had not converged, 23 µT off, with exit status 0)."""
    cal = fluxcal.Calibration(offset=CALS["nT"].offset, matrix=CALS["nT"].matrix, field_norm=CALS["nT"].field_norm,
                              units="nT", summary={**CALS["nT"].summary, "converged": False, "warnings": [
                                  "second step not converged after 50 iterations"]})
    with pytest.raises(ValueError, match="did not converge: the result is an intermediate iterate"):
        export_c(cal, tmp_path / "p.h", name="p")
    assert not (tmp_path / "p.h").exists()
    export_c(cal, tmp_path / "p.h", name="p", force=True)
    assert "WARNING (exported with --force): the calibration's fit did not converge" in (tmp_path / "p.h").read_text()


def test_one_clamped_sample_sets_the_overflow_flag_in_c_cplusplus_and_python(tmp_path):
    """A single sample at INT32_MAX among small ones (a clamped conversion): the filter's state does not saturate,
    but the sample was not what the sensor read — the C header, the C++ filter and Python all say so."""
    f = FixedArKalman((0.6, -0.3, 0.2), 0.5, 0.3, frac_bits=28)
    header = tmp_path / "p.h"
    export_c(CALS["nT"], header, name="p", kalman=f)
    series = np.zeros(256, dtype=np.int64)
    series[100] = 2 ** 31 - 1
    driver = KALMAN_C_DRIVER.replace("p_kalman_test_input[k]", "(k == 100 ? INT32_MAX : 0)")
    (tmp_path / "one.c").write_text(driver.replace("HEADER", header.name))
    subprocess.run([compiler(), "-std=c99", "-Wall", "-Werror", f"-I{tmp_path}", str(tmp_path / "one.c"), "-o",
                    str(tmp_path / "one")], check=True)
    lines = subprocess.run([str(tmp_path / "one")], capture_output=True, text=True, check=True).stdout.split("\n")
    expected = FixedArKalman((0.6, -0.3, 0.2), 0.5, 0.3, frac_bits=28)
    np.testing.assert_array_equal([int(v) for v in lines[:-3]], expected.filter_int(series))
    assert lines[-3] == "overflow 1" and expected.overflowed
    clean = FixedArKalman((0.6, -0.3, 0.2), 0.5, 0.3, frac_bits=28)
    clean.filter_int(np.where(series > 0, 2 ** 30, 0))
    assert not clean.overflowed


def test_input_range_sizes_the_format_for_the_sensors_full_scale(tmp_path):
    """An int16 sensor in counts: by default the format holds 2 × the calibration readings' extent, so a
    reading near full scale (a magnet, a motor) saturates; with the sensor's full scale as the input range
    every reading up to it is corrected within the stated bound, in C too."""
    s = simulated(13, n=1500, field_norm=450.0)  # about 0.45 G at 1000 counts per gauss
    cal = fluxcal.calibrate(np.rint(s.readings), units="counts")
    default = fixed_point(cal)
    full_scale = fixed_point(cal, input_range=32768)
    assert default.input_range < 32768 <= full_scale.input_range and "--input-range" in full_scale.range_note
    rails = np.array([[32767.0, -32768.0, 32767.0], [-32768.0, -32768.0, -32768.0], [32767.0, 32767.0, -1.0]])
    assert default.apply_int(default.to_fixed(rails))[1]  # the default range saturates there
    h_q, saturated = full_scale.apply_int(full_scale.to_fixed(rails))
    assert not saturated
    np.testing.assert_array_less(np.abs(h_q * full_scale.out_fmt.lsb - cal.apply(rails)), full_scale.error_bound)
    # the header's test vector holds the corners of ±32768, and the C code reproduces Python there
    header = tmp_path / "p.h"
    export_c(cal, header, name="p", input_range=32768)
    rows, self_test = run_driver(tmp_path, header)
    assert self_test == 0 and np.max(np.abs(rows[:, :3])) >= 32767 and not rows[:, 9].any()
    # what cannot be: a range below the calibration's own readings, a format too small for it, no calibration
    with pytest.raises(ValueError, match=r"--input-range 100 counts: smaller than the calibration readings' extent"):
        fixed_point(cal, input_range=100)
    with pytest.raises(ValueError, match=r"--q-format Q12.19: readings up to the input range ±32768 counts .* "
                                         r"use at least Q1[5-7]\.1[4-6]"):
        fixed_point(cal, "Q12.19", input_range=32768)
    with pytest.raises(ValueError, match="give a calibration"):
        export_c(None, tmp_path / "x.h", kalman=FixedArKalman((0.5,), 0.5, 0.3, frac_bits=28), input_range=10)
    saved = cal.save(tmp_path / "cal.json")
    r = run_cli("export-c", saved, "-o", tmp_path / "cli.h", "--input-range", "32768")
    assert r.returncode == 0 and "inputs |m| ≤ 32768" in r.stdout, r.stdout + r.stderr
    r = run_cli("export-c", saved, "-o", tmp_path / "cli.h", "--input-range", "-5")
    assert r.returncode == 2 and "--input-range" in r.stderr and "Traceback" not in r.stderr


def test_headers_that_differ_in_case_or_clash_with_a_part_are_not_skipped_silently(tmp_path):
    """`--name mag` and `--name MAG` shared one include guard (MAG_H), and `--name comb_kalman` the guard of comb's
    Kalman part: the second header was skipped without a word (a blind check). The guard keeps the name's case."""
    export_c(CALS["nT"], tmp_path / "lower.h", name="mag")
    export_c(CALS["Gauss"], tmp_path / "upper.h", name="MAG")
    lower, upper = (tmp_path / "lower.h").read_text(), (tmp_path / "upper.h").read_text()
    # (the guard also holds a hash of the content: test_two_calibrations_of_one_name_in_one_file_clash_aloud)
    assert re.search(r"#ifndef FLUXCAL_mag_[0-9A-F]{8}_H", lower) and \
        re.search(r"#ifndef FLUXCAL_MAG_[0-9A-F]{8}_H", upper)
    source = tmp_path / "two.c"
    source.write_text('#include "lower.h"\n#include "upper.h"\nint main(void) { return mag_self_test() + '
                      'MAG_self_test(); }\n')
    build = subprocess.run([compiler(), "-std=c99", f"-I{tmp_path}", str(source), "-o", str(tmp_path / "two")],
                           capture_output=True, text=True)
    assert "MAG_FIELD_NORM\" redefined" in build.stderr or "MAG_FIELD_NORM' redefined" in build.stderr, build.stderr


def test_a_forced_header_names_the_undetermined_parameters_and_defines_a_macro(tmp_path):
    """A cap of directions: the refusal quoted a coverage note ("poorly determined") instead of the warning that
    names b2, a00, …; a forced header said it only in a comment (a blind check)."""
    cal = fluxcal.Calibration(offset=np.zeros(3), matrix=np.eye(3), field_norm=50.0, units="uT", summary={
        "identifiable": False, "warnings": ["poor coverage: the offset and matrix along the thin direction are poorly "
                                            "determined", "not identifiable: the data do not determine b2, a00"]})
    with pytest.raises(ValueError, match="not identifiable: the data do not determine b2, a00"):
        export_c(cal, tmp_path / "cap.h")
    export_c(cal, tmp_path / "cap.h", force=True)
    assert "#define CAP_EXPORTED_WITH_FORCE 1" in (tmp_path / "cap.h").read_text()


def test_an_existing_file_that_is_no_header_is_not_overwritten(tmp_path):
    kept = tmp_path / "run.csv"
    kept.write_text("mx,my,mz\n1,2,3\n")
    with pytest.raises(ValueError, match="run.csv exists and is no C header"):
        export_c(CALS["nT"], kept)
    assert kept.read_text() == "mx,my,mz\n1,2,3\n"


def _difference_drift_model():
    foct = sim.foct_zero_bias(rng=np.random.default_rng(1), hold_s=300, ramp_s=150, self_heating=3.0)
    model, _ = drift.fit_pipeline(foct.columns["zero_bias"], foct.columns["temp"], foct.columns["temp_outside"],
                                  regressor="difference")
    return model


@pytest.mark.parametrize("ranges", ["with difference ranges", "saved without them"])
def test_drift_function_refuses_a_temperature_that_is_not_a_number(tmp_path, ranges):
    """`x < lo || x > hi` is false for NaN: with the difference regressor a NaN temp_outside (a failed outside
    thermometer) returned 0, "ok", with f = NaN, where a NaN temp returned 1 and Python refuses it (a blind check).
    Every non-number in either input now returns 1 with f = 0, also for a model saved without the difference's
    fitted ranges."""
    model = _difference_drift_model()
    if ranges == "saved without them":
        for seg in model.segments:
            del seg["difference_range"]
        assert model.difference_ranges is None
    header = tmp_path / "p.h"
    export_c(None, header, name="p", drift=model)
    source, exe = tmp_path / "drift.c", tmp_path / "drift"
    source.write_text(DRIFT_DRIVER.replace("HEADER", header.name))
    subprocess.run([compiler(), "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-Wfloat-equal", "-O2",
                    f"-I{tmp_path}", str(source), "-o", str(exe)], check=True)
    seg = model.segments[0]
    temp = float(np.mean(seg["range"]))
    outside = temp - (float(np.mean(model.difference_ranges[0])) if model.difference_ranges else 5.0)
    expected = float(model.evaluate([temp], [outside])[0])
    pairs = [(temp, "nan"), ("nan", outside), (temp, "inf"), (temp, "-inf"), ("inf", "inf"), ("nan", "nan"),
             (temp, outside)]
    run = subprocess.run([str(exe)], input="".join(f"{t} {o}\n" for t, o in pairs), capture_output=True, text=True,
                         check=True)
    lines = run.stdout.split("\n")
    assert lines[-2] == "self_test 0"
    flags = [int(line.split()[0]) for line in lines[:-2]]
    values = [float(line.split()[1]) for line in lines[:-2]]
    assert flags == [1, 1, 1, 1, 1, 1, 0], run.stdout
    assert values[:-1] == [0.0] * 6 and values[-1] == pytest.approx(expected, rel=1e-12)
    assert "or either is NaN or inf" in header.read_text()  # (and the header says so)
    with pytest.raises(ValueError, match="temp_outside"):  # what the C function now agrees with
        model.evaluate([temp], [np.nan])


def test_a_drift_model_with_a_non_stationary_noise_model_is_refused(tmp_path):
    """A drift model's AR noise model edited to [2, -0.5, 0.1] (a root of magnitude 1.75) was exported with its
    Kalman filter without a word, and that filter amplified the noise (a blind check): load_kalman's own refusal
    never fired, since ArKalman starts a non-stationary model from 10 (q + r), a finite σ. Refused now, naming the
    file and the field; so is a saved filter whose signal format would follow from that σ (frac_bits not given)."""
    foct = sim.foct_zero_bias(rng=np.random.default_rng(1), hold_s=300, ramp_s=150)
    model, _ = drift.fit_pipeline(foct.columns["zero_bias"], foct.columns["temp"])
    path = model.save(tmp_path / "drift.json")
    export_c(None, tmp_path / "fine.h", kalman=path)  # the fitted model itself is exported
    data = json.loads(path.read_text())
    data["ar"]["coefficients"], data["ar"]["order"] = [2.0, -0.5, 0.1], 3
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(data))
    words = r"edited.json: ar.coefficients \[2, -0.5, 0.1\]: the AR model is not stationary \(a root of magnitude 1.7"
    with pytest.raises(ValueError, match=words):
        export_c(None, tmp_path / "k.h", kalman=edited)
    r = run_cli("export-c", "-o", tmp_path / "cli.h", "--kalman", edited)
    assert r.returncode == 2 and "not stationary" in r.stderr and not (tmp_path / "cli.h").exists(), r.stderr
    # a saved filter: with its format stated it may be a deliberate random walk; without, its 8 σ rule is void
    walk = FixedArKalman((1.0,), 0.01, 0.1, frac_bits=20)
    export_c(None, tmp_path / "walk.h", kalman=save_kalman(walk, tmp_path / "walk.json"))
    walk.frac_bits = None
    with pytest.raises(ValueError, match=r"walk.json: ar_coeffs \[1\]: the AR model is not stationary .* give "
                                         r"frac_bits"):
        load_kalman(save_kalman(walk, tmp_path / "walk.json"))


def test_a_format_or_range_that_wastes_the_precision_is_said(tmp_path):
    """A typo'd --input-range 1e9 (for 1e3 µT) gave Q30.1 and a bound of 3.6 µT on a 48 µT field, --q-format Q31.0 on
    µT readings 0.56 µT, written without a word (a blind check). Said now, when the bound exceeds the calibration's
    own residual RMS: in ExportResult.warnings, the command line's output and the header; integer counts in
    Q31.0, whose bound is under the residual, and the default formats say nothing."""
    s = simulated(21, n=1500, noise=0.003, field_norm=48.0)
    cal = fluxcal.calibrate(s.readings, field_norm=48.0, units="uT")
    residual = cal.summary["residual_rms"]
    quiet = export_c(cal, tmp_path / "default.h")
    assert quiet.warnings == [] and "WARNING" not in (tmp_path / "default.h").read_text()
    q31 = export_c(cal, tmp_path / "q31.h", q_format="Q31.0")
    assert q31.fixed.error_bound > residual
    assert len(q31.warnings) == 1 and re.match(r"--q-format Q31.0: the fixed-point error bound E = 0\.\d+ uT .* "
                                               r"above the calibration's own residual RMS .*\(leave --q-format out\)",
                                               q31.warnings[0]), q31.warnings
    assert "WARNING: --q-format Q31.0" in (tmp_path / "q31.h").read_text()
    wide = export_c(cal, tmp_path / "wide.h", input_range=1e9)
    assert len(wide.warnings) == 1 and wide.warnings[0].startswith("--input-range 1e+09 uT: the fixed-point error ")
    assert "is that the sensor's full scale in uT?" in wide.warnings[0]
    saved = cal.save(tmp_path / "cal.json")
    r = run_cli("export-c", saved, "-o", tmp_path / "cli.h", "--input-range", "1e9")
    assert r.returncode == 0 and "warning: --input-range 1e+09 uT" in r.stdout, r.stdout + r.stderr
    # counts: Q31.0 (integer counts fed as they are) rounds to a share of a count, under the noise: nothing said
    counts = fluxcal.calibrate(np.rint(s.readings * 10.0), field_norm=48.0, units="counts")
    counts.field_units = "uT"
    natural = export_c(counts, tmp_path / "counts.h", q_format="Q31.0", input_range=32768)
    assert natural.fixed.error_bound < counts.summary["residual_rms"] and natural.warnings == []
    # without a residual in the summary the line is 0.1 % of the field
    bare = fluxcal.Calibration(offset=cal.offset, matrix=cal.matrix, field_norm=48.0, units="uT")
    assert export_c(bare, tmp_path / "bare.h").warnings == []
    assert "0.1% of the field" in export_c(bare, tmp_path / "bare.h", q_format="Q31.0").warnings[0]


def test_two_calibrations_of_one_name_in_one_file_clash_aloud(tmp_path):
    """magcal.h of one calibration and magcal.h of another in two folders shared the guard FLUXCAL_magcal_H: in one
    C file the second was skipped without a word and the first one's constants used (a blind check). The guard now
    holds a hash of the content: the two clash (redefinition), the same header included twice is still skipped."""
    for folder, which in (("s1", "nT"), ("s2", "Gauss"), ("s3", "nT")):
        (tmp_path / folder).mkdir()
        export_c(CALS[which], tmp_path / folder / "magcal.h")
    main = "int main(void) { return magcal_self_test(); }\n"
    for name, includes, builds in (("two", ("s1", "s2"), False), ("same", ("s1", "s1"), True),
                                   ("copy", ("s1", "s3"), True)):
        source = tmp_path / f"{name}.c"
        source.write_text("".join(f'#include "{f}/magcal.h"\n' for f in includes) + main)
        build = subprocess.run([compiler(), "-std=c99", "-Wall", "-Wextra", "-Werror", f"-I{tmp_path}", str(source),
                                "-o", str(tmp_path / name)], capture_output=True, text=True)
        assert (build.returncode == 0) == builds, (name, build.stderr)
        if not builds:
            assert "redefinition" in build.stderr, build.stderr
        else:
            assert subprocess.run([str(tmp_path / name)]).returncode == 0
    guards = [re.search(r"#ifndef (FLUXCAL_magcal_[0-9A-F]{8}_H)", (tmp_path / f / "magcal.h").read_text()).group(1)
              for f in ("s1", "s2", "s3")]
    assert guards[0] != guards[1] and guards[0] == guards[2]  # the content, not the folder, makes the guard


def test_a_mirrored_magnitude_calibration_is_refused(tmp_path):
    """A magnitude calibration's matrix negated by hand (det A < 0: every field mirrored) was exported and passed its
    self-test (a blind check). fluxcal's magnitude calibrations are symmetric positive definite ((W W^T)^-1/2):
    such a matrix is refused naming the field, unless forced (the header then says it); a reference-vector fit's full
    matrix may be a mirror (axes of the other handedness) and is exported with a warning."""
    cal = CALS["nT"]
    negated = fluxcal.Calibration(offset=cal.offset, matrix=-cal.matrix, field_norm=cal.field_norm, units="nT",
                                  model=cal.model, summary=cal.summary)
    with pytest.raises(ValueError, match=r"cal: matrix: symmetric with eigenvalues -.* \(det A = -.*\): not positive "
                                         r"definite, so it mirrors the field"):
        export_c(negated, tmp_path / "n.h")
    assert not (tmp_path / "n.h").exists()
    saved = negated.save(tmp_path / "negated.json")
    r = run_cli("export-c", saved, "-o", tmp_path / "cli.h")
    assert r.returncode == 2 and "not positive definite" in r.stderr and not (tmp_path / "cli.h").exists()
    export_c(negated, tmp_path / "n.h", force=True)
    text = (tmp_path / "n.h").read_text()
    assert "WARNING (exported with --force): matrix: symmetric" in text and "N_EXPORTED_WITH_FORCE 1" in text
    # a turn of 180° (two axes negated, det > 0) is no magnitude calibration either
    turned = fluxcal.Calibration(offset=cal.offset, matrix=cal.matrix @ np.diag([-1.0, -1.0, 1.0]) @ cal.matrix
                                 / np.abs(cal.matrix).max(), field_norm=cal.field_norm, units="nT")
    assert np.allclose(turned.matrix, turned.matrix.T) and np.linalg.det(turned.matrix) > 0
    with pytest.raises(ValueError, match="not positive definite, so it turns over the field"):
        export_c(turned, tmp_path / "t.h")
    # a vector fit's matrix (not symmetric) that is a mirror: exported, said
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    vector = fluxcal.Calibration(offset=cal.offset, matrix=np.diag([1.0, 1.0, -1.0]) @ rotation @ cal.matrix,
                                 field_norm=cal.field_norm, units="nT", summary={"parameter_names": [
                                     "b0", "b1", "b2", "w00", "w01", "w02", "w10", "w11", "w12", "w20", "w21", "w22"]})
    result = export_c(vector, tmp_path / "v.h")
    assert len(result.warnings) == 1 and result.warnings[0].startswith("cal: matrix: det A = -")
    assert "WARNING: matrix: det A = -" in (tmp_path / "v.h").read_text()
    # fluxcal's own calibrations are not touched
    for which in CALS:
        assert export_c(CALS[which], tmp_path / f"{which}.h").warnings == []


def test_a_matrix_entry_that_is_a_json_bool_is_refused(tmp_path):
    """A hand edit's `true` as a matrix entry was read as 1.0 and exported (a blind check)."""
    data = json.loads(CALS["nT"].save(tmp_path / "cal.json").read_text())
    data["matrix"][0][0] = True
    (tmp_path / "bool.json").write_text(json.dumps(data))
    r = run_cli("export-c", tmp_path / "bool.json", "-o", tmp_path / "b.h")
    assert r.returncode == 2 and "matrix" in r.stderr and not (tmp_path / "b.h").exists()
