"""NumPy `.npz` recordings (and plain `.npy` arrays).

Layout written (and read) by fluxcal: one 1-D float array per column under the column's name, plus
the entry `__fluxcal__`, a JSON string

    {"kind": "fluxcal recording", "columns": ["t", "mx", ...], "units": {...}, "metadata": {...}}

that keeps the column order, units and metadata. An `.npz` fluxcal did not write is read by the rule
of `recording_from_arrays` (the N×3 magnetometer matrix, or mx,my,mz vectors); a `.npy` holds one
N×3 array. Files are read with allow_pickle=False: a recording never executes code.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .csv import readable_file
from .recording import Recording, recording_from_arrays

META_KEY = "__fluxcal__"
KIND = "fluxcal recording"


def header(rec: Recording) -> dict:
    """The JSON description of a recording that the binary formats store beside its columns."""
    from ..calibration import _jsonable

    return {"kind": KIND, "columns": list(rec.columns), "units": dict(rec.units),
            "metadata": _jsonable(dict(rec.metadata))}


def parse_header(text, source: str) -> dict:
    """The stored JSON description; ValueError naming the file when it is not one."""
    try:
        data = json.loads(text)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: the fluxcal description ({META_KEY}) is not valid JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("kind") != KIND or not isinstance(data.get("columns"), list):
        raise ValueError(f"{source}: the fluxcal description is not a recording header")
    return data


def write_npz(path, rec: Recording) -> Path:
    """Write a recording as an uncompressed .npz (the columns stay memory-mappable by NumPy)."""
    path = Path(path)
    arrays = {name: np.asarray(values, dtype=float) for name, values in rec.columns.items()}
    if META_KEY in arrays:
        raise ValueError(f"{path}: a column may not be named {META_KEY!r}")
    with path.open("wb") as f:  # a file object keeps NumPy from appending ".npz" to other suffixes
        np.savez(f, **arrays, **{META_KEY: np.array(json.dumps(header(rec)))})
    return path


def read_npz(path, columns=None, units: str | None = None, matrix: str | None = None) -> Recording:
    """Read an .npz (or .npy) recording. `matrix`: the N×3 magnetometer variable of a foreign file.
    A truncated or corrupt file is a ValueError naming it."""
    path = readable_file(path)
    try:
        with path.open("rb") as f:
            npy = f.read(6) == b"\x93NUMPY"
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    kind = ".npy" if npy else ".npz"
    try:
        if npy:
            variables = {"readings": np.load(path, allow_pickle=False)}
        else:
            with np.load(path, allow_pickle=False) as loaded:
                variables = {name: loaded[name] for name in loaded.files}
    except Exception as exc:  # zipfile, zlib, struct and format errors alike mean a damaged file
        raise ValueError(f"{path}: not a readable {kind} file (truncated or corrupt? "
                         f"{type(exc).__name__}: {exc})") from None
    if META_KEY in variables:
        info = parse_header(variables.pop(META_KEY).item(), str(path))
        missing = [c for c in info["columns"] if c not in variables]
        if missing:
            raise ValueError(f"{path}: columns {', '.join(missing)} are described but not stored")
        rec = Recording(columns={c: variables[c] for c in info["columns"]}, units=dict(info.get("units", {})),
                        metadata=dict(info.get("metadata", {})), source=str(path))
    else:
        rec = recording_from_arrays(variables, str(path), matrix=matrix, columns=columns)
    return rec.choose(columns, units)

