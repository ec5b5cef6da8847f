"""MATLAB `.mat` recordings (SciPy's loadmat/savemat: MAT v5, what MATLAB writes by default).

Layout written by fluxcal: one top-level column vector per column (`load rec.mat; plot(t, mx)` works in
MATLAB), plus `fluxcal_recording`, a char array holding the JSON description (column order, units,
metadata and the MATLAB name of each column: names that are not MATLAB identifiers are changed, e.g.
"mx [nT]" → "mx__nT_", and restored on reading).

Files fluxcal did not write are read by the rule of `recording_from_arrays`: the N×3 variable named by
`matrix` (the CLI's `--columns NAME`), else mx,my,mz (or x,y,z) vectors, else the only N×3 variable —
what a MATLAB magcal user has. Fields of top-level structs count as variables too. MAT v7.3 files are
HDF5, which SciPy cannot read: read_recording reads them with h5py (fluxcal.io.hdf5).
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from .csv import readable_file
from .npz import header, parse_header
from .recording import Recording, recording_from_arrays

META_VAR = "fluxcal_recording"
_IDENTIFIER = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,62}$")


def _matlab_names(columns) -> dict:
    """Column name → a distinct valid MATLAB identifier."""
    out, used = {}, {META_VAR}
    for name in columns:
        var = name if _IDENTIFIER.match(name) else re.sub(r"[^A-Za-z0-9_]", "_", name)
        if not var or not var[0].isalpha():
            var = "c_" + var
        var = var[:63]
        base, k = var, 1
        while var in used:
            k += 1
            var = f"{base[:60]}_{k}"
        used.add(var)
        out[name] = var
    return out


def write_mat(path, rec: Recording) -> Path:
    path = Path(path)
    names = _matlab_names(rec.columns)
    info = {**header(rec), "variables": names}
    variables = {names[c]: np.asarray(v, dtype=float).reshape(-1, 1) for c, v in rec.columns.items()}
    variables[META_VAR] = json.dumps(info)
    from scipy.io import savemat

    with path.open("wb") as f:  # a file object keeps SciPy from appending ".mat" to other suffixes
        savemat(f, variables, do_compression=True)
    return path


def read_mat(path, columns=None, units: str | None = None, matrix: str | None = None) -> Recording:
    """Read a .mat recording. `matrix`: the N×3 magnetometer variable of a foreign file.
    A truncated or corrupt file is a ValueError naming it."""
    from scipy.io import loadmat

    path = readable_file(path)
    try:
        with path.open("rb") as f:
            if f.read(512)[:128].find(b"MATLAB 7.3") >= 0:
                raise ValueError(f"{path}: a MATLAB v7.3 (HDF5) file, which SciPy cannot read; fluxcal.read_recording "
                                 "reads it with h5py (fluxcal[hdf5]), or save it in MATLAB with save(name, '-v7')")
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        raw = loadmat(path, squeeze_me=False, struct_as_record=False, chars_as_strings=True)
    except Exception as exc:  # scipy raises ValueError, TypeError, zlib.error, MatReadError… for damaged files
        raise ValueError(f"{path}: not a readable MATLAB .mat file (truncated or corrupt? "
                         f"{type(exc).__name__}: {exc})") from None
    variables = {}
    for name, value in raw.items():
        if name.startswith("__"):  # __header__, __version__, __globals__
            continue
        for key, item in _flatten(name, value):
            variables[key if key not in variables else f"{name}.{key}"] = item
    if META_VAR in variables:
        info = parse_header(variables.pop(META_VAR), str(path))
        names = info.get("variables", {c: c for c in info["columns"]})
        missing = [c for c in info["columns"] if names.get(c) not in variables]
        if missing:
            raise ValueError(f"{path}: columns {', '.join(missing)} are described but not stored")
        rec = Recording(columns={c: np.ravel(variables[names[c]]) for c in info["columns"]},
                        units=dict(info.get("units", {})), metadata=dict(info.get("metadata", {})), source=str(path))
    else:
        rec = recording_from_arrays(variables, str(path), matrix=matrix, columns=columns)
    return rec.choose(columns, units)


def _flatten(name, value):
    """(name, array or str) pairs: char arrays become strings, a 1×1 struct gives its fields."""
    if isinstance(value, np.ndarray) and value.dtype.kind == "U":
        yield name, "\n".join(str(s) for s in value.ravel())
    elif isinstance(value, np.ndarray) and value.dtype == object and value.size == 1 \
            and hasattr(value.item(), "_fieldnames"):
        struct = value.item()
        for field in struct._fieldnames:
            yield from _flatten(field, getattr(struct, field))
    elif hasattr(value, "_fieldnames"):
        for field in value._fieldnames:
            yield from _flatten(field, getattr(value, field))
    else:
        yield name, value
