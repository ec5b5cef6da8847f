"""Sim-to-real diagnosis: where a real sensor departs from its model, which unmodelled effect causes
it, and how far the gap shrinks once that effect is modelled — proved on held-out regimes.

    result = fluxcal.diagnose(recording)            # or diagnose(samples, t=..., temp=..., field_norm=...)
    print(result.text())
    result.ranking[0]["effect"], result.significant
    result.save_json("out.json"); result.report("report_dir")

1. Where: the base model's residuals, normalised by the noise (σ given, or estimated from third
   differences of the readings in time order, which a smooth motion hardly disturbs — from those of the
   base model's residuals when the motion is fast for the sample rate, steps between held positions, or
   rows that are no time series at all; at least LSB/√12 on an ADC's grid), broken down by orientation,
   temperature, current (when logged), time and per axis, with a test per regime and a whiteness test over time.
2. Which: every candidate effect of `fluxcal.sim.effects.CANDIDATES` (whose regressors the recording
   has) gets a score test at the base fit, a check that existing parameters do not absorb it, then a
   refit of the augmented model (Ceres, `refine_terms`): likelihood-ratio statistic, ΔAIC, ΔBIC (a time the
   search placed — an event's edge inside the recording, a pass's closest approach and passage time — counts
   as a parameter there, as a drift's profiled time constant does). The
   p-value comes from the likelihood ratio under the augmented fit's own noise model, so slow correlated
   noise is not taken for a drift or a disturbance: an AR(p) of its residuals whitens both fits, and a
   wandering offset (each axis's offset a random walk through 32 times of the recording, its strength by
   maximum likelihood; the turning sensor mixes the axes' wander in the magnitude's series, where the AR
   model cannot see it) — the smaller of the two ratios.
3. How far: each candidate is fitted again without a held-out regime — the last quarter in time, the hottest
   quarter, the highest-current quarter, a cap of unseen orientations, or interleaved blocks of time for
   events (for a short event, of its own span, and judged where it acts: `_event_block`) — and judged there:
   the gap √(RMS² − σ²) before and after, and the downstream errors (field; with
   reference vectors the direction and, given the down direction, the heading). Effects are added greedily
   while the best one is significant (whitened likelihood ratio after a Bonferroni correction over the
   candidates and their alternatives, ΔBIC < 0, and a held-out improvement that a block test finds
   significant: a sign-flip test of block means, each block twice the noise's correlation length in sample).
   Features non-linear in the signal are computed from the fitted model's noise-free reading, so the reading
   noise cannot fake them, then again at the signal (and, for cross_axis' exact 1/(1 + s_e/H_k), the
   coefficients) of the fit that models them; their absorption is judged on the part not affine in the
   signal (offset and matrix hold the rest). Saturation's limit and saturation_knee's knee are profiled (a 1-D
   search, each step a linear refit) and counted as a parameter. An effect in the transducer (a gain, a non-linearity) is tried
   acting on the field with the offset (the platform's hard iron) and on the field alone (the sensor's own
   electronic offset, added after it), counted as alternatives; the row's `offset_kind` says which when the
   data decide. A fit with a sign the effect's physics forbids (an expanding saturation, a hysteresis ahead
   of its input) is not that effect. Systematic effects are tried before noise models: a systematic effect
   predicts unseen regimes, correlated noise only the next sample. When none is significant but one passed
   every in-sample test, it is added on trial: two large effects at once (a magnet passing while the offset
   jumps) each fail the held-out test while the other is unmodelled, and are kept together when each passes
   with the other modelled (`found_with`). A moving_dipole is a box in time (a magnet switched on or moved
   within it) or a pass on a straight line at a steady speed (Anderson's functions: closest approach
   `closest_s`, passage time `passage_s`), whichever fits better. An accepted event's time profile is refined
   (a box: Legendre degree by BIC; a pass: the magnitude's second-order term), so that what a low-order shape
   leaves is not taken for a second event. An event recurs (a magnet carried past twice, a device switched on
   twice): once it is found, another episode of it, apart in time from those found (one inside them is what
   their shape leaves), competes with the other candidates in every round, and on trial the first and a second
   episode are kept together when each passes with the other modelled; the episodes share the effect's block
   (`episodes` in its row), each counted against `max_effects`.
4. What the recording cannot decide: a candidate that explained it as well as an accepted effect (ΔBIC
   within CONFOUND_BIC = 10) and adds nothing once that effect is modelled is its rival, reported in
   `Diagnosis.confounded` and as CANNOT TELL APART with what would separate them (a temperature that
   follows time makes temp_offset and offset_drift one effect). A special case of a rival (saturation is
   the cubic with equal coefficients) is not one: the next round tests the extra terms. Beside an event (a
   free course in time), a temperature or current effect that takes out the same departure (their fits change
   the residuals alike, cosine ≥ 0.95) and explains at least half as much is a rival too, whatever the ΔBIC
   gap — the free course fits whatever the logged quantity drives, and noise besides —, reported when it is no
   longer significant once the event is modelled.

The cable-current ring (seed 000) has its own base model and candidates, with the same statistics:

    from fluxcal.diagnose import diagnose_cable      # (fluxcal.diagnose itself is the function above)
    d = diagnose_cable(readings, ring, currents=reference, rotations_deg=rot, positions=known_positions,
                       calibration=ring_calibration)

readings (snapshots, sensors, 2) in tesla against the ring's straight-infinite-conductor model (positions
shared, reference currents or currents fitted per snapshot, the per-sensor calibration's gains and offsets
refined); candidates `helical_lay`, `finite_length`, `sensor_position_error`, `z_leakage`
(`fluxcal.sim.cable_effects`); held out: unseen rotations, the highest current level, later snapshots;
downstream: the error of the currents measured on the held-out snapshots (A and %) and of the conductor
positions. See `fluxcal.diagnose.cable`.
"""
import functools

from threadpoolctl import threadpool_limits

from . import cable as _cable
from . import core as _core
from . import limits as _limits
from .cable import CableDiagnosis
from .core import MODELS, Diagnosis, estimate_noise
from .limits import DetectionLimits


def _one_blas_thread(fn):
    """`fn` with BLAS held to one thread. A diagnosis multiplies thousands of small matrices (N × a few
    columns): BLAS threads cost more than they give there, and on a machine busy with other work OpenBLAS'
    spinning threads made it 5× slower (airborne recording: 28 s of CPU with one thread, 158 s with two)."""
    @functools.wraps(fn)
    def one_thread(*args, **kwargs):
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)
    return one_thread


diagnose = _one_blas_thread(_core.diagnose)
diagnose_cable = _one_blas_thread(_cable.diagnose_cable)
detection_limits = _one_blas_thread(_limits.detection_limits)

__all__ = ["MODELS", "CableDiagnosis", "DetectionLimits", "Diagnosis", "detection_limits", "diagnose", "diagnose_cable",
           "estimate_noise"]
