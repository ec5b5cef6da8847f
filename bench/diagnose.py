"""The sim-to-real diagnosis on every real recording, and its blind record on withheld-effect simulations.

    .venv/bin/python bench/diagnose.py --real ../shared/data/real          # real recordings
    .venv/bin/python bench/diagnose.py --trials 10                          # withheld-effect table
    .venv/bin/python bench/diagnose.py --inject ../shared/data/real --trials 3  # added to real recordings
    .venv/bin/python bench/diagnose.py --limits ../shared/data/real         # detection limits of each real recording
    .venv/bin/python bench/diagnose.py --timing                             # 20 000 readings, all candidates
    .venv/bin/python bench/diagnose.py --warm-up 10                         # temperature following time
    .venv/bin/python bench/diagnose.py --settling 10                        # an offset settling in time (a warm-up)
    .venv/bin/python bench/diagnose.py --time-pairs 10                      # a drift, a step, a current together
    .venv/bin/python bench/diagnose.py --family-pairs 10                    # saturation beside a drift, …
    .venv/bin/python bench/diagnose.py --against 12                         # a drift or warm-up beside a step
    .venv/bin/python bench/diagnose.py --jitter 5                           # a motor current jittering
    .venv/bin/python bench/diagnose.py --wander 20                          # short recordings of correlated noise
    .venv/bin/python bench/diagnose.py --trials 5 --noise 0.2 --rate 10     # other noise, rates, --duration
    .venv/bin/python bench/diagnose.py --nulls 30 --noise 0.5               # nothing withheld only
    .venv/bin/python bench/diagnose.py --passes 12                          # a magnet carried past (straight line)
    .venv/bin/python bench/diagnose.py --twice 12                           # a magnet carried past twice
    .venv/bin/python bench/diagnose.py --trials 3 --hard-iron 5 --soft-iron 0.15  # a real sensor's errors

Prints Markdown tables for bench/RESULTS.md.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import fluxcal
from fluxcal import attitude
from fluxcal.diagnose import diagnose
from fluxcal.diagnose.core import refused
from fluxcal.diagnose.report import unconfirmed
from fluxcal.sim.effects import CANDIDATES
from fluxcal.sim.inject import inject, injectable
from fluxcal.sim.withheld import CURRENT, HARD_IRON, SOFT_IRON, withheld_trial


def recordings(folder: Path):
    """The real recordings: (name, readings, diagnose keyword arguments, the arguments `inject` needs)."""
    phone = fluxcal.read_csv(folder / "phone_acc_mag.csv")
    yield "phone_acc_mag.csv", phone, {}, {"gravity": phone.acceleration()}
    handheld = fluxcal.read_csv(folder / "handheld_set1.csv", columns="x,y,z")
    yield "handheld_set1.csv", handheld, {"field_norm": 0.47}, {"field_norm": 0.47}
    q = np.loadtxt(folder / "qmc5883l_filtered.csv", delimiter=",", skiprows=3)  # Fs 50 Hz, 60 s static first
    t = np.arange(len(q)) / 50.0
    yield "qmc5883l_filtered.csv", q, {"t": t, "units": "counts", "source": "qmc5883l_filtered.csv"}, {"t": t}
    a = np.loadtxt(folder / "airborne_flt1002_02.tsv")
    ref = attitude.reference_vectors(a[:, 7:10], a[:, 4], a[:, 5], a[:, 6])
    down = attitude.reference_vectors([0.0, 0.0, 1.0], a[:, 4], a[:, 5], a[:, 6])
    yield ("airborne_flt1002_02.tsv", a[:, 1:4],
           {"t": a[:, 0], "reference": ref, "gravity": down, "units": "nT", "source": "airborne_flt1002_02.tsv"},
           {"t": a[:, 0], "reference": ref, "gravity": down})


def real(folder: Path):
    print("| recording | model | readings | noise σ (est.) | base gap | found (in order) | top candidates: ΔBIC, held-out gap before → after |")
    print("|---|---|---:|---:|---:|---|---|")
    for name, rec, kw, _ in recordings(folder):
        t0 = time.perf_counter()
        d = diagnose(rec, **kw)
        _row(name, d, time.perf_counter() - t0)


def injected(folder: Path, n: int, only=None, strength: float = 1.0, which=None):
    """Each candidate added to each real recording (`which`: names starting so; default all) at a typical
    magnitude times `strength` (fluxcal.sim.inject), n seeds: found (accepted), found first, what else
    was accepted beyond the recording's own effects, and why the added effect was missed (_why_missed)."""
    print("| recording (own effects) | added effect | size (RMS % of the field) | found | found first | "
          "also accepted, beyond the recording's own | missed: why | s/trial |")
    print("|---|---|---:|---:|---:|---|---|---:|")
    for name, rec, kw, inject_kw in recordings(folder):
        if which and not any(name.startswith(w) for w in which):
            continue
        m = rec.samples() if hasattr(rec, "samples") else rec
        own = diagnose(m, **{**kw, **inject(m, [], 0, **inject_kw).kwargs}).accepted  # with a made-up temperature
        cal = fluxcal.calibrate(m, field_norm=kw.get("field_norm"), reference=kw.get("reference"))
        H = float(np.mean(np.linalg.norm(cal.apply(m), axis=1)))
        for effect in [x for x in injectable(kw.get("reference") is not None) if not only or x in only]:
            found, first, extra, missed, sizes, t0 = 0, 0, {}, {}, [], time.perf_counter()
            for seed in range(n):
                inj = inject(m, [effect], seed, strength=strength, **inject_kw)
                sizes.append(np.sqrt(np.mean(np.sum(((inj.readings - m) @ np.asarray(cal.matrix).T) ** 2, axis=1))) / H)
                d = diagnose(inj.readings, **{**kw, **inj.kwargs})
                found += effect in d.accepted
                if effect not in d.accepted:
                    why = _why_missed(next(r for r in d.ranking if r["effect"] == effect))
                    missed[why] = missed.get(why, 0) + 1
                first += bool(d.accepted) and d.accepted[0] == effect
                for a in d.accepted:
                    if a != effect and a not in own:
                        extra[a] = extra.get(a, 0) + 1
            print(f"| {name} ({', '.join(own) or 'nothing'}) | {effect} | {100 * np.median(sizes):.2g} | {found}/{n} | "
                  f"{first}/{n} | {', '.join(f'{k} {v}' for k, v in extra.items()) or '—'} | "
                  f"{', '.join(f'{k} {v}' for k, v in missed.items()) or '—'} | "
                  f"{(time.perf_counter() - t0) / n:.1f} |", flush=True)


def _why_missed(row) -> str:
    """Why a candidate's row was not accepted: absorbed or not judged, refused by a guard, evidence in the
    recording that the held-out readings do not confirm ("held out"), too little in the recording ("in
    sample"), or significant but another effect chosen (or the quantization step not given as the noise)."""
    if row.get("heldout_gap_before") is None:
        return "absorbed"
    if refused(row):
        return "refused"
    if unconfirmed(row):
        return "held out"
    return "in sample" if row.get("unmet") else "not chosen"


def _row(name, d, seconds):
    top = "; ".join(f"{r['effect']} {r['delta_bic']:.0f}, {_g(r.get('heldout_gap_before'))} → {_g(r.get('heldout_gap_after'))}"
                    for r in d.ranking[:3])
    found = ", ".join(a + "".join(f" (or {r['effect']}: cannot tell apart)" for r in d.confounded.get(a, []))
                      for a in d.accepted)
    print(f"| {name} | {d.model} | {d.where['overall']['n']} | {d.noise_sigma:.3g} | {d.where['overall']['gap']:.3g} | "
          f"{found or 'nothing'} | {top} |  ({seconds:.1f} s)")


def _g(x):
    return "—" if x is None else f"{x:.3g}"


def trials(n: int, only=None, **sim):
    print("| withheld effect | base model | ranked first & significant | found alone (no extra effect) | "
          "flagged 'cannot tell apart' | held-out gap shrink (median, min) | s/trial |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for cls in [c for c in CANDIDATES if not only or c.name in only]:
        hits, alone, confounded, shrink, t0 = 0, 0, 0, [], time.perf_counter()
        for seed in range(n):
            r, kw = withheld_trial([cls.name], seed, **sim)
            d = diagnose(r.readings, **kw)
            top = d.ranking[0]
            alone += d.accepted == [cls.name]
            confounded += bool(d.confounded)
            if top["effect"] == cls.name and top["significant"]:
                hits += 1
                shrink.append(1 - top["heldout_gap_after"] / top["heldout_gap_before"])
        med = f"{np.median(shrink):.2f}, {np.min(shrink):.2f}" if shrink else "—"
        print(f"| {cls.name} | {kw['model']} | {hits}/{n} | {alone}/{n} | {confounded}/{n} | {med} | "
              f"{(time.perf_counter() - t0) / n:.1f} |")
    if not only:
        nulls(2 * n, **sim)


def nulls(n: int, **sim):
    """Nothing withheld: how many trials report nothing, and what the false finds were."""
    quiet, found = 0, {}
    for seed in range(n):
        r, kw = withheld_trial([], 200 + seed, **sim)
        d = diagnose(r.readings, **kw)
        quiet += not d.significant
        for a in d.accepted:
            found[a] = found.get(a, 0) + 1
    wrong = ", ".join(f"{k} {v}" for k, v in found.items()) or "—"
    print(f"| (nothing withheld) | ellipsoid | {quiet}/{n} report nothing | found: {wrong} | — |")


def passes(n: int, sizes=(0.015, 0.04)):
    """A magnet carried past on a straight line (`MovingDipole.straight_pass`, closest at 30–70 % of the trial,
    passage time 0.5–3 s) against magnitudes and against reference vectors: found as moving_dipole with the pass
    search, and with the box alone (the search before 2026-11-30); the closest approach's error over the passage
    time where found."""
    from unittest import mock

    from fluxcal.sim.effects import MovingDipole
    from fluxcal.sim.withheld import DURATION

    print("| model | size (of the field) | found, pass or box | median \\|closest − truth\\| / T | found, box alone |")
    print("|---|---:|---:|---:|---:|")
    for model in (None, "vector"):
        for size in sizes:
            found, errors, boxed = 0, [], 0
            for seed in range(n):
                rng = np.random.default_rng(200 + seed)
                t_close, t_pass = rng.uniform(0.3, 0.7) * DURATION, rng.uniform(0.5, 3.0)
                dipole = MovingDipole.straight_pass(50.0, rng, t_close, t_pass, size)
                r, kw = withheld_trial(["moving_dipole"], seed, model=model, dipole=dipole)
                d = diagnose(r.readings, **kw)
                if "moving_dipole" in d.accepted:
                    found += 1
                    row = next(x for x in d.ranking if x["effect"] == "moving_dipole")
                    if row.get("closest_s") is not None:
                        errors.append(abs(row["closest_s"] - t_close) / t_pass)
                with mock.patch.object(MovingDipole, "_search_pass", classmethod(lambda c, ctx, s: (None, -np.inf, 0))):
                    boxed += "moving_dipole" in diagnose(r.readings, **kw).accepted
            error = f"{np.median(errors):.3f} ({len(errors)} as a pass)" if errors else "—"
            print(f"| {model or 'magnitude'} | {100 * size:.1f} % | {found}/{n} | {error} | {boxed}/{n} |")


def twice(n: int, size: float = 0.03):
    """A magnet carried past twice (two `MovingDipole.straight_pass`, closest at 15–40 % and 60–85 % of the trial,
    passage times 0.5–3 s, each `size` of the field at most) against magnitudes and against reference vectors:
    how often both passes are found as episodes of moving_dipole (each closest approach within a quarter of its
    passage time), one, neither, and any other effect named."""
    from fluxcal.sim.effects import MovingDipole
    from fluxcal.sim.withheld import DURATION

    print("| model | size (of the field) | both | one | neither | other effects named "
          "| median \\|closest − truth\\| / T |")
    print("|---|---:|---:|---:|---:|---|---:|")
    for model in (None, "vector"):
        counts, others, errors = {2: 0, 1: 0, 0: 0}, {}, []
        for seed in range(n):
            rng = np.random.default_rng(300 + seed)
            timing = sorted((rng.uniform(*span) * DURATION, rng.uniform(0.5, 3.0))
                            for span in ((0.15, 0.4), (0.6, 0.85)))
            dipoles = [MovingDipole.straight_pass(50.0, rng, t_close, t_pass, size) for t_close, t_pass in timing]
            r, kw = withheld_trial(["moving_dipole"], seed, model=model, dipole=dipoles)
            d = diagnose(r.readings, **kw)
            for name in set(d.accepted) - {"moving_dipole", "colored_noise"}:
                others[name] = others.get(name, 0) + 1
            row = next(x for x in d.ranking if x["effect"] == "moving_dipole")
            episodes = (row.get("episodes") or [row]) if "moving_dipole" in d.accepted else []
            found = 0
            for t_close, t_pass in timing:  # a pass is found when an episode's closest approach is near its own
                near = [abs(e["closest_s"] - t_close) / t_pass for e in episodes if e.get("closest_s") is not None]
                if near and min(near) < 0.25:
                    found += 1
                    errors.append(min(near))
            counts[found] += 1
        named = ", ".join(f"{k} {v}" for k, v in sorted(others.items())) or "—"
        error = f"{np.median(errors):.3f}" if errors else "—"
        print(f"| {model or 'magnitude'} | {100 * size:.1f} % | {counts[2]}/{n} | {counts[1]}/{n} | {counts[0]}/{n} | "
              f"{named} | {error} |")


def warm_up(n: int):
    """Temperature-driven and time-driven effects when the temperature follows time (a warm-up)."""
    ramps = {"linear 20 → 35 °C": lambda t: 20.0 + 15.0 * t / t[-1],
             "exponential, τ = 30 s": lambda t: 20.0 + 15.0 * (1 - np.exp(-t / 30.0))}
    print("| withheld effect | warm-up | r(T, t) | right effect accepted | flagged 'cannot tell apart' with | "
          "wrong and not flagged |")
    print("|---|---|---:|---:|---|---:|")
    for name in ("offset_drift", "temp_offset", "temp_scale"):
        for label, ramp in ramps.items():
            right, wrong, flagged = 0, 0, {}
            for seed in range(n):
                r, kw = withheld_trial([name], seed, temperature=ramp)
                d = diagnose(r.readings, **kw)
                rivals = [x["effect"] for x in d.confounded.get(d.accepted[0], [])] if d.accepted else []
                for x in rivals:
                    flagged[x] = flagged.get(x, 0) + 1
                right += bool(d.accepted) and d.accepted[0] == name
                wrong += (not d.accepted or d.accepted[0] != name) and name not in rivals
            corr = np.corrcoef(kw["temp"], kw["t"])[0, 1]
            print(f"| {name} | {label} | {corr:.3f} | {right}/{n} | "
                  f"{', '.join(f'{k} {v}/{n}' for k, v in flagged.items()) or '—'} | {wrong}/{n} |")


def settling(n: int):
    """An offset settling exponentially in time (a warm-up after power-on, no temperature logged): is it
    called offset_drift with its time constant, or an offset step, or a drift plus a step?"""
    from fluxcal.sim.effects import HardIron, OffsetDrift, SoftIron, WhiteNoise
    from fluxcal.sim.scene import tumble
    from fluxcal.sim.simulate import simulate
    from fluxcal.sim.withheld import FIELD, NOISE

    print("| time constant (60 s recording) | offset_drift alone | its time constant (median, worst error) | "
          "called linear | what else was accepted |")
    print("|---:|---:|---:|---:|---|")
    for tau in (1.0, 3.0, 12.0, 40.0, 120.0):
        alone, errors, linear, other = 0, [], 0, {}
        for seed in range(n):
            rng = np.random.default_rng(seed)
            settled = rng.choice([-1, 1], 3) * rng.uniform(0.005, 0.008, 3) * np.linalg.norm(FIELD)
            W = np.diag(1 + rng.uniform(-0.05, 0.05, 3))
            b = rng.uniform(-1, 1, 3) * 0.2 * np.linalg.norm(FIELD) / np.sqrt(3)
            scene = tumble(60.0, rng=rng)
            r = simulate(scene, [SoftIron(W), HardIron(b), OffsetDrift(settled / tau, warmup_s=tau), WhiteNoise(NOISE)],
                         FIELD, rng)
            d = diagnose(r.readings, t=r.t, field_norm=float(np.linalg.norm(FIELD)))
            alone += d.accepted == ["offset_drift"]
            row = next(x for x in d.ranking if x["effect"] == "offset_drift")
            if "offset_drift" in d.accepted and row.get("warmup_s") is None:
                linear += 1
            elif "offset_drift" in d.accepted:
                errors.append(abs(row["warmup_s"] / tau - 1))
            for a in d.accepted:
                if a != "offset_drift":
                    other[a] = other.get(a, 0) + 1
        err = f"{100 * np.median(errors):.0f} %, {100 * np.max(errors):.0f} %" if errors else "—"
        print(f"| {tau:g} s | {alone}/{n} | {err} | {linear}/{n} | "
              f"{', '.join(f'{k} {v}' for k, v in other.items()) or '—'} |")


TIME_PAIRS = (("offset_drift", "offset_step"), ("offset_drift", "motor_current"), ("offset_step", "motor_current"))


def time_pairs(n: int):
    """Two effects that both follow time together (a drift and a step, a drift and a motor's current, a step and
    a motor's current; 300 s at 20 Hz, each effect 0.3–0.6 µT per axis at its largest): are both found, each
    where it is, and nothing else? The search places the first one found while the other is unmodelled."""
    from fluxcal.sim.effects import HardIron, MotorCurrent, OffsetDrift, OffsetStep, SoftIron, WhiteNoise
    from fluxcal.sim.scene import tumble
    from fluxcal.sim.simulate import simulate
    from fluxcal.sim.withheld import FIELD, NOISE

    print("| pair (300 s, 20 Hz) | both found, nothing else | step within 1 s (of those with a step found) | "
          "residual RMS ≤ 1.05 σ | what else was accepted |")
    print("|---|---:|---:|---:|---|")
    for pair in TIME_PAIRS:
        both, placed, steps, flat, other = 0, 0, 0, 0, {}
        for seed in range(n):
            rng = np.random.default_rng(seed)
            size = lambda: rng.choice([-1, 1], 3) * rng.uniform(0.3, 0.6, 3)  # noqa: E731
            at = rng.uniform(40.0, 260.0)
            made = {"offset_drift": lambda: OffsetDrift(size() / 300.0), "offset_step": lambda: OffsetStep(size(), at),
                    "motor_current": lambda: MotorCurrent(size() / 20.0)}
            scene = tumble(300.0, rate_hz=20.0, rng=rng, current=CURRENT if "motor_current" in pair else None)
            effects = [SoftIron(np.diag(1 + rng.uniform(-0.05, 0.05, 3))), HardIron([4.0, -3.0, 2.0])]
            r = simulate(scene, effects + [made[name]() for name in pair] + [WhiteNoise(NOISE)], FIELD, rng)
            d = diagnose(r.readings, t=r.t, field_norm=float(np.linalg.norm(FIELD)), current=r.current)
            both += sorted(d.accepted) == sorted(pair)
            flat += d.remaining["overall"]["rms_z"] <= 1.05
            if "offset_step" in pair and "offset_step" in d.accepted:
                row = next(x for x in d.to_dict()["ranking"] if x["effect"] == "offset_step")
                steps += 1
                placed += abs(row["jump_s"] - at) < 1.0 and row["back_s"] is None
            for a in d.accepted:
                if a not in pair:
                    other[a] = other.get(a, 0) + 1
        step = f"{placed}/{steps}" if "offset_step" in pair else "—"
        print(f"| {' + '.join(pair)} | {both}/{n} | {step} | {flat}/{n} | "
              f"{', '.join(f'{k} {v}' for k, v in other.items()) or '—'} |", flush=True)


def against(n: int):
    """A drift and a step against it (linear ±[1, −0.8, 0.6] µT over 300 s, the step ∓[0.8, −0.5, 0.4] µT at
    60–240 s), and a warm-up [0.6, −0.5, 0.45] µT (τ 35–50 s) beside a step ±[0.8, −0.5, 0.4] µT: both found, the
    step where it is and staying, and how often a second search with the drift taken first was the one kept
    (tests/python/test_diagnose.py::test_a_drift_and_a_step_are_found_in_another_order draws the same)."""
    from fluxcal.sim.effects import HardIron, OffsetDrift, OffsetStep, SoftIron, WhiteNoise
    from fluxcal.sim.scene import tumble
    from fluxcal.sim.simulate import simulate
    from fluxcal.sim.withheld import FIELD, NOISE

    print("| drift beside a step (300 s, 20 Hz) | both found, nothing else | step within 1 s, staying | "
          "residual RMS ≤ 1.05 σ | kept from a second search | what was found instead |")
    print("|---|---:|---:|---:|---:|---|")
    for warm_up in (False, True):
        both, placed, flat, second, instead = 0, 0, 0, 0, {}
        for seed in range(n):
            rng = np.random.default_rng(seed)
            scene = tumble(300.0, rate_hz=20.0, rng=rng)
            sign, at = rng.choice([-1, 1]), rng.uniform(60, 240)
            step = np.array([0.8, -0.5, 0.4])
            if warm_up:
                tau = rng.uniform(35, 50)
                course, jump = OffsetDrift(np.array([0.6, -0.5, 0.45]) / tau, warmup_s=tau), sign * step
            else:
                course, jump = OffsetDrift(sign * np.array([1.0, -0.8, 0.6]) / 300.0), -sign * step
            effects = [SoftIron(np.diag([1.03, 0.97, 1.01])), HardIron([4.0, -3.0, 2.0]), course, OffsetStep(jump, at),
                       WhiteNoise(NOISE)]
            r = simulate(scene, effects, FIELD, rng)
            d = diagnose(r.readings, t=r.t, field_norm=float(np.linalg.norm(FIELD)))
            rows = {x["effect"]: x for x in d.to_dict()["ranking"]}
            found = sorted(d.accepted) == ["offset_drift", "offset_step"]
            both += found
            placed += found and abs(rows["offset_step"]["jump_s"] - at) < 1.0 and rows["offset_step"]["back_s"] is None
            flat += d.remaining["overall"]["rms_z"] <= 1.05
            second += found and "another_order" in rows["offset_drift"]
            if not found:
                key = ", ".join(d.accepted) or "nothing"
                instead[key] = instead.get(key, 0) + 1
        print(f"| {'warm-up' if warm_up else 'linear drift against it'} | {both}/{n} | {placed}/{n} | {flat}/{n} | "
              f"{second}/{n} | {'; '.join(f'{k} ({v})' for k, v in instead.items()) or '—'} |", flush=True)


def jitter(n: int):
    """A motor's current jittering from reading to reading (blocks of 0–15 A, ± 5 A white while on; withheld_trial's
    motor_current otherwise): the noise σ against the truth, and is the motor found alone?"""
    from fluxcal.sim.scene import jittering
    from fluxcal.sim.withheld import NOISE

    print("| seed | noise σ / truth | found | k error / SE (largest) |")
    print("|---|---:|---|---:|")
    for seed in range(n):
        result, kwargs = withheld_trial(["motor_current"], seed, current=jittering(np.random.default_rng(100 + seed)))
        d = diagnose(result.readings, **kwargs)
        row = next(r for r in d.ranking if r["effect"] == "motor_current")
        truth = next(e.k for e in result.effects if e.name == "motor_current")
        z = np.max(np.abs(np.asarray(row["coefficients"]) - truth) / np.asarray(row["standard_errors"]))
        print(f"| {seed} | {d.noise_sigma / NOISE:.3f} | {', '.join(d.accepted) or 'nothing'} | {z:.2f} |", flush=True)


def wander(n: int):
    """Short recordings (30–60 s at 10–50 Hz, drawn per seed) with correlated noise (`colored_noise`, typical: AR(1)
    of 0.05–0.1 µT): an event named where there is none, and a true step or magnet beside the same noise found?"""
    events = {"offset_step", "moving_dipole"}
    print("| withheld | trials | an event named (false) | the withheld event found | mean time, s |")
    print("|---|---:|---:|---:|---:|")
    for extra in ([], ["offset_step"], ["moving_dipole"]):
        false = found = 0
        spent = 0.0
        for seed in range(n):
            rng = np.random.default_rng(seed)
            duration, rate = float(rng.choice([30.0, 45.0, 60.0])), float(rng.choice([10.0, 20.0, 50.0]))
            result, kwargs = withheld_trial(["colored_noise"] + extra, seed, duration_s=duration, rate_hz=rate)
            start = time.perf_counter()
            d = diagnose(result.readings, **kwargs)
            spent += time.perf_counter() - start
            false += bool((events - set(extra)) & set(d.accepted))
            found += bool(extra) and extra[0] in d.accepted
        print(f"| colored_noise{''.join(' + ' + e for e in extra)} | {n} | {false} | "
              f"{f'{found}' if extra else '—'} | {spent / n:.1f} |", flush=True)


FAMILY_PAIRS = (("saturation", "temp_scale"), ("saturation", "offset_drift"), ("nonlinearity_cubic", "temp_offset"),
                ("hysteresis", "temp_scale"), ("cross_axis", "motor_current"))


def family_pairs(n: int):
    """A transducer effect beside one that follows the temperature, time or a current (`withheld_trial`, typical
    sizes): is each named, and not its kin (the cubic for saturation)?"""
    print("| pair | both named, nothing else | what was named instead |")
    print("|---|---:|---|")
    for pair in FAMILY_PAIRS:
        right, instead = 0, {}
        for seed in range(n):
            r, kw = withheld_trial(list(pair), seed)
            d = diagnose(r.readings, **kw)
            right += sorted(d.accepted) == sorted(pair)
            if sorted(d.accepted) != sorted(pair):
                key = " + ".join(d.accepted) or "nothing"
                instead[key] = instead.get(key, 0) + 1
        print(f"| {' + '.join(pair)} | {right}/{n} | {', '.join(f'{k} ({v})' for k, v in instead.items()) or '—'} |",
              flush=True)


def margins(n: int, only=None, **sim):
    """How far the accepted effects of blind trials stay from the degenerate-fit guards (fluxcal.diagnose.core):
    the held-out field error over the noise floor (refused below NOISE_FLOOR_FRACTION), the distortion (refused
    above MAX_DISTORTION) and the held-out field error after over before (refused above 1)."""
    print("| withheld effect | trials | accepted rows | field error / floor (min) | distortion (max) | "
          "field error after / before (max) |")
    print("|---|---:|---:|---:|---:|---:|")
    for cls in [c for c in CANDIDATES if not only or c.name in only]:
        rows = []
        for seed in range(n):
            r, kw = withheld_trial([cls.name], seed, **sim)
            d = diagnose(r.readings, **kw)
            rows += [x for x in d.ranking if x["significant"] and x.get("heldout_noise_floor")]
        floor = min((x["field_error_after"] / x["heldout_noise_floor"] for x in rows), default=None)
        distortion = max((x["distortion"] for x in rows), default=None)
        rise = max((x["field_error_after"] / x["field_error_before"] for x in rows), default=None)
        print(f"| {cls.name} | {n} | {len(rows)} | {_g(floor)} | {_g(distortion)} | {_g(rise)} |", flush=True)


def limits(folder: Path, seeds: int, which=None):
    """Each real recording's detection limits (`fluxcal.detection_limits`): a column per recording, the size
    confirmed from (not at), % of the field, and what the full diagnosis named there."""
    from fluxcal.diagnose import detection_limits

    columns = {}
    for name, rec, kw, inject_kw in recordings(folder):
        if which and not any(name.startswith(w) for w in which):
            continue
        t0 = time.perf_counter()
        columns[name] = detection_limits(rec, seeds=seeds, **{**kw, "gravity": inject_kw.get("gravity")})
        columns[name].seconds = time.perf_counter() - t0
    names = list(dict.fromkeys(r["effect"] for d in columns.values() for r in d.rows))

    def cell(d, effect):
        r = next((r for r in d.rows if r["effect"] == effect), None)
        if r is None or r["status"] == "not_tried":
            return "—"
        if r["status"] in ("in_recording", "absorbed"):
            return "in the recording" if r["status"] == "in_recording" else "absorbed by the base"
        unit = " ms" if effect == "time_offset" else " %"
        if r["status"] == "not_found":
            return f"> {r['not_at']:.3g}{unit}"
        below = f" (not {r['not_at']:.3g})" if r["not_at"] is not None else ""
        full = r["full_run"]
        named = "first" if full[:1] == [effect] else "found" if effect in full else \
            "→ " + ", ".join(full) if full else "→ nothing"
        return f"{r['found_at']:.3g}{unit}{below}; {named}"

    print("| effect | " + " | ".join(columns) + " |")
    print("|---|" + "---|" * len(columns))
    for effect in names:
        print(f"| {effect} | " + " | ".join(cell(d, effect) for d in columns.values()) + " |")
    print("| seconds | " + " | ".join(f"{d.seconds:.0f}" for d in columns.values()) + " |")


def timing():
    r, kw = withheld_trial(["temp_scale"], 1, duration_s=400.0)  # 20 000 readings
    t0 = time.perf_counter()
    d = diagnose(r.readings, **kw, progress=True)
    print(f"{len(r.readings)} readings, {len(d.ranking)} candidates: {time.perf_counter() - t0:.1f} s; found {d.accepted}")


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--real", type=Path)
    p.add_argument("--inject", type=Path, help="folder of the real recordings: each candidate added to each")
    p.add_argument("--strength", type=float, default=1.0, help="--inject: the added effects' size × this")
    p.add_argument("--recordings", nargs="*", help="--inject, --limits: only the recordings whose names start so")
    p.add_argument("--limits", type=Path, help="folder of the real recordings: each one's detection limits")
    p.add_argument("--seeds", type=int, default=3, help="--limits: shapes per size")
    p.add_argument("--trials", type=int)
    p.add_argument("--timing", action="store_true")
    p.add_argument("--nulls", type=int, help="only the trials with nothing withheld")
    p.add_argument("--passes", type=int, help="trials per model and size: a magnet carried past on a straight line")
    p.add_argument("--twice", type=int, help="trials per model: a magnet carried past twice")
    p.add_argument("--margins", type=int, help="trials per effect: the accepted rows' distance from the guards")
    p.add_argument("--warm-up", type=int)
    p.add_argument("--settling", type=int, help="trials per time constant of an offset settling in time")
    p.add_argument("--time-pairs", type=int, help="trials per pair of effects that both follow time")
    p.add_argument("--family-pairs", type=int, help="trials per pair: a transducer effect beside another")
    p.add_argument("--against", type=int, help="trials per case: a drift, or a warm-up, beside a step")
    p.add_argument("--jitter", type=int, help="trials: a motor's current jittering from reading to reading")
    p.add_argument("--wander", type=int, help="trials per case: short recordings of correlated noise, an event or none")
    p.add_argument("--only", nargs="*", help="withheld effects to run (default all)")
    p.add_argument("--noise", type=float, default=0.05, help="white noise σ of the trials, µT (field 50 µT)")
    p.add_argument("--rate", type=float, default=50.0, help="sample rate of the trials, Hz")
    p.add_argument("--duration", type=float, default=60.0, help="length of the trials, s")
    p.add_argument("--hard-iron", type=float, default=HARD_IRON,
                   help="the trials' largest hard iron |b|, field norms (each axis within ±that·H/√3)")
    p.add_argument("--soft-iron", type=float, default=SOFT_IRON,
                   help="the trials' scale errors ±that (soft iron's off-diagonal ±0.6 of it)")
    args = p.parse_args()
    sim = dict(noise=args.noise, rate_hz=args.rate, duration_s=args.duration, hard_iron=args.hard_iron,
               soft_iron=args.soft_iron)
    if args.real:
        real(args.real)
    if args.nulls:
        nulls(args.nulls, **sim)
    if args.passes:
        passes(args.passes)
    if args.twice:
        twice(args.twice)
    if args.limits:
        limits(args.limits, args.seeds, args.recordings)
    if args.inject:
        injected(args.inject, args.trials or 3, args.only, args.strength, args.recordings)
    elif args.trials:
        trials(args.trials, args.only, **sim)
    if args.margins:
        margins(args.margins, args.only, **sim)
    if args.timing:
        timing()
    for table in (warm_up, settling, time_pairs, family_pairs, against, jitter, wander):  # (each option: its trials)
        if getattr(args, table.__name__):
            table(getattr(args, table.__name__))
