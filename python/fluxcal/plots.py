"""Plots (matplotlib, no screen needed)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def before_after(raw, calibration, path, title: str = "") -> Path:
    """Raw readings and corrected fields (three projections each) and |h| before/after, to `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    raw = np.asarray(raw, dtype=float)
    h = calibration.apply(raw)
    H = calibration.field_norm
    u = f" [{calibration.units}]" if calibration.units else ""
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.8))
    pairs = ((0, 1, "x–y"), (0, 2, "x–z"), (1, 2, "y–z"))
    for (i, j, label), colour in zip(pairs, ("C0", "C1", "C2")):
        ax[0].plot(raw[:, i], raw[:, j], ".", ms=1.5, color=colour, label=label)
        ax[1].plot(h[:, i], h[:, j], ".", ms=1.5, color=colour, label=label)
    circle = np.linspace(0, 2 * np.pi, 361)
    ax[1].plot(H * np.cos(circle), H * np.sin(circle), "k--", lw=0.8, label=f"|h| = {H:.4g}")
    for a, name in ((ax[0], "raw readings" + u), (ax[1], "corrected" + u)):
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
    ax[2].set_title("field magnitude")
    ax[2].legend(markerscale=6, fontsize=8)
    ax[2].grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
