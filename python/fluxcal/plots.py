"""Plots (matplotlib, no screen needed)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

TICKS = 6         # at most this many intervals between tick labels on an axis
THOUSANDS = 1e4   # an axis reaching this far is labelled in k (thousands), M…: "-50k", not "-50000"


def before_after(raw, calibration, path, title: str = "") -> Path:
    """Raw readings and corrected fields (three projections each; a planar calibration's plane) and |h|
    before/after, to `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = before_after_figure(raw, calibration, title)
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def before_after_figure(raw, calibration, title: str = ""):
    """The figure `before_after` saves (a matplotlib Figure; close it with matplotlib.pyplot.close)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    raw = np.asarray(raw, dtype=float)
    h = calibration.apply(raw)
    H = calibration.field_norm
    unit, h_unit = calibration.units or "", calibration.h_units or ""  # (h's unit differs from counts' readings)
    u = f" [{unit}]" if unit else ""
    hu = f" [{h_unit}]" if h_unit else ""
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.8))
    plane = calibration.summary.get("plane_basis") if calibration.summary.get("method") == "planar" else None
    if plane is not None:  # a planar calibration: the plane's two axes, |h| the horizontal field in it
        basis = np.asarray(plane, dtype=float)
        raw, h = (raw, h) if raw.shape[1] == 2 else (raw @ basis.T, h @ basis.T)
        names = calibration.summary.get("plane_axes", ["1", "2"])
        pairs = ((0, 1, f"{names[0]}–{names[1]}"),)
    else:
        pairs = ((0, 1, "x–y"), (0, 2, "x–z"), (1, 2, "y–z"))
    for (i, j, label), colour in zip(pairs, ("C0", "C1", "C2")):
        ax[0].plot(raw[:, i], raw[:, j], ".", ms=1.5, color=colour, label=label)
        ax[1].plot(h[:, i], h[:, j], ".", ms=1.5, color=colour, label=label)
    circle = np.linspace(0, 2 * np.pi, 361)
    ax[1].plot(H * np.cos(circle), H * np.sin(circle), "k--", lw=0.8, label=f"|h| = {_number(H)} {h_unit}".rstrip())
    for a, name in ((ax[0], "raw readings" + u), (ax[1], "corrected" + hu)):
        a.set_title(name)
        a.set_aspect("equal", adjustable="datalim")
        a.legend(markerscale=6, fontsize=8)
        a.grid(alpha=0.3)
    raw_norm = np.linalg.norm(raw, axis=1)
    ax[2].plot(100 * (raw_norm / raw_norm.mean() - 1), ".", ms=1, color="0.6",
               label=f"raw |m|: std/mean {100 * raw_norm.std() / raw_norm.mean():.2f} %")
    norm = np.linalg.norm(h, axis=1)
    ax[2].plot(100 * (norm / H - 1), ".", ms=1, color="C3",
               label=f"corrected |h|: std/mean {100 * norm.std() / norm.mean():.3f} %")
    ax[2].set_xlabel("sample")
    ax[2].set_ylabel("deviation of the magnitude [%]")
    ax[2].set_title("field magnitude" if plane is None else "horizontal field magnitude")
    ax[2].legend(markerscale=6, fontsize=8)
    ax[2].grid(alpha=0.3)
    for a in ax:
        _legible(a)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def _number(x: float) -> str:
    """A field's magnitude as people write it: 53941 nT, 50 uT, 5.0012e-05 T — not 5.394e+04."""
    return format(float(format(float(x), ".5g")), "g")


def _legible(ax) -> None:
    """Tick labels that do not run into each other: at most TICKS intervals, and an axis that reaches THOUSANDS
    in thousands ("-50k", the unit in its title). Readings in nT were labelled -80000-60000-40000… in one run: the
    equal aspect widens the x range after the default locator has sized its labels for three characters."""
    from matplotlib.ticker import EngFormatter, MaxNLocator

    for axis, data in ((ax.xaxis, "get_xdata"), (ax.yaxis, "get_ydata")):
        axis.set_major_locator(MaxNLocator(nbins=TICKS, steps=[1, 2, 2.5, 5, 10]))
        values = np.concatenate([np.asarray(getattr(line, data)(), dtype=float).ravel() for line in ax.get_lines()]
                                or [np.zeros(1)])
        values = values[np.isfinite(values)]
        if values.size and np.max(np.abs(values)) >= THOUSANDS:
            axis.set_major_formatter(EngFormatter(sep=""))
