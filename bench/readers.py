"""Wall-clock benchmark of fluxcal.read_recording on the layouts it takes, against pandas on the same file.

    PYTHONPATH=python .venv/bin/python bench/readers.py [--n 100000] [--repeat 3]

One seeded recording (t, mx, my, mz, 8 significant digits) is written in each layout into a temporary
folder; each file is read by fluxcal.read_recording (content sniffing, parsing, column recognition,
checks) and, where pandas has a reader for the layout, by pandas (read_csv with the right separator and
decimal, read_json(lines=True), read_excel) — the peer an engineer would otherwise script. Both readers'
magnetometer columns are compared with the written values. Times: best of --repeat runs after one warm-up
(best_time). Ratio = fluxcal / pandas (below 1: fluxcal faster).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from functools import reduce
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _timing import best_time, machine_facts, table  # noqa: E402

import fluxcal  # noqa: E402


def layouts(folder: Path, t, m):
    """(name, path, pandas reader or None) of each layout written."""
    rows = list(zip(t.tolist(), *m.T.tolist()))
    out = []
    p = folder / "table.csv"
    p.write_text("t,mx,my,mz\n" + "".join(f"{a:.3f},{x:.8g},{y:.8g},{z:.8g}\n" for a, x, y, z in rows))
    out.append(("CSV (comma, header)", p, lambda p: _pd().read_csv(p)))
    p = folder / "excel_eu.csv"
    p.write_text("t [s];Bx [uT];By [uT];Bz [uT]\n" + "".join(
        f"{a:.3f};{x:.8g};{y:.8g};{z:.8g}\n".replace(".", ",") for a, x, y, z in rows))
    out.append(("';' with decimal commas", p, lambda p: _pd().read_csv(p, sep=";", decimal=",")))
    p = folder / "capture.txt"
    p.write_text("".join(f"Mag X: {x:.8g}  Y: {y:.8g}  Z: {z:.8g}  uT\n" for _, x, y, z in rows))
    out.append(("labelled lines (serial monitor)", p, None))
    p = folder / "log.jsonl"
    p.write_text("".join(json.dumps({"t": a, "mag": {"x": x, "y": y, "z": z}}) + "\n" for a, x, y, z in rows))
    out.append(("JSON Lines (nested)", p, lambda p: _pd().json_normalize(_pd().read_json(p, lines=True)
                                                                          .to_dict("records"))))
    p = folder / "vn100.txt"
    lines = []
    for x, y, z in m.tolist():
        body = f"VNMAG,{x:+.6f},{y:+.6f},{z:+.6f}"
        lines.append(f"${body}*{reduce(lambda c, b: c ^ b, body.encode(), 0):02X}\n")
    p.write_text("".join(lines))
    out.append(("$VNMAG sentences (checksummed)", p, None))
    return out


def _pd():
    import pandas

    return pandas


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rng = np.random.default_rng(7)
    h = rng.normal(size=(args.n, 3))
    m = 50.0 * h / np.linalg.norm(h, axis=1, keepdims=True) + [12.0, -30.0, 5.0]
    t = np.arange(args.n) * 0.02
    pandas = _pd()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, path, peer in layouts(Path(tmp), t, m):
            rec = fluxcal.read_recording(path)
            err = float(np.max(np.abs(rec.samples() - m)))
            ours = best_time(lambda: fluxcal.read_recording(path).samples(), args.repeat)
            theirs = best_time(lambda: peer(path), args.repeat) if peer else None
            rows.append([name, f"{path.stat().st_size / 1e6:.1f}", f"{ours:.3f}",
                         f"{theirs:.3f}" if theirs else "—", f"{ours / theirs:.2f}" if theirs else "—",
                         f"{args.n / ours / 1e6:.2f}", f"{err:.1e}"])
    print(f"N = {args.n} readings per file, best of {args.repeat}")
    table(["layout", "MB", "fluxcal s", "pandas s", "ratio", "M rows/s", "max |error|"], rows)
    print()
    table(["fact", "value"], [list(f) for f in machine_facts(numpy=np.__version__, pandas=pandas.__version__)])


if __name__ == "__main__":
    main()
