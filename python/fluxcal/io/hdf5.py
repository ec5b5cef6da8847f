"""HDF5 files (h5py, `pip install fluxcal[hdf5]`): MATLAB v7.3 `.mat` files, and instruments' own HDF5.

Every numeric dataset is a variable named by its path without the leading "/" ("imu/mag"). MATLAB v7.3
stores arrays column-major, so a MATLAB N×3 matrix sits in the file as 3×N: its 2-D arrays are transposed
back; its char arrays (MATLAB_class "char") become text; cells, structs' references and MATLAB's own
"#refs#"/"#subsystem#" groups are left out and named in metadata["ignored_variables"]. Then the rule of
`recording_from_arrays` picks the magnetometer: the N×3 variable that `columns` names, else mx,my,mz (or
x,y,z) vectors, else the only N×3 variable. A dataset's "units" (or "unit") attribute is its unit.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .csv import readable_file
from .recording import Recording, recording_from_arrays

_MATLAB_INTERNAL = ("#refs#", "#subsystem#")


def _text(value) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else str(value)


def _variables(f, matlab: bool):
    """({name: array or str}, {name: unit}, [ignored]) of the file's datasets."""
    import h5py

    variables, units, ignored = {}, {}, []

    def visit(name, obj):
        if not isinstance(obj, h5py.Dataset) or name.split("/")[0] in _MATLAB_INTERNAL:
            return
        cls = _text(obj.attrs.get("MATLAB_class", b""))
        if cls == "char":
            variables[name] = "".join(map(chr, np.asarray(obj[()]).T.ravel()))
            return
        if obj.dtype.kind not in "biuf" or (matlab and cls in ("cell", "struct")):
            ignored.append(f"{name} ({cls or obj.dtype})")
            return
        value = np.asarray(obj[()])
        variables[name] = value.T if matlab and value.ndim == 2 else value
        unit = obj.attrs.get("units", obj.attrs.get("unit"))
        if unit is not None:
            units[name] = _text(np.asarray(unit).ravel()[0] if np.ndim(unit) else unit)

    f.visititems(visit)
    return variables, units, ignored


def read_hdf5(path, columns=None, units: str | None = None, matrix: str | None = None) -> Recording:
    path = readable_file(path)
    try:
        import h5py
    except ImportError:
        raise ValueError(f"{path}: an HDF5 file (MATLAB v7.3?); reading it needs h5py (pip install "
                         "'fluxcal[hdf5]'), or in MATLAB save it with save(name, '-v7')") from None
    with path.open("rb") as f:
        matlab = b"MATLAB 7.3" in f.read(128)
    try:
        with h5py.File(path, "r") as f:
            variables, unit_of, ignored = _variables(f, matlab)
    except OSError as exc:  # h5py's error for a truncated or corrupt file
        raise ValueError(f"{path}: not a readable HDF5 file (truncated or corrupt? {exc})") from None
    rec = recording_from_arrays(variables, str(path), matrix=matrix, columns=columns)
    chosen = rec.metadata.get("magnetometer_variable")
    if chosen in unit_of:
        rec.units.update(dict.fromkeys(("mx", "my", "mz"), unit_of[chosen]))
    rec.units.update({name: u for name, u in unit_of.items() if name in rec.columns})
    if ignored:
        rec.metadata["ignored_variables"] = "; ".join(filter(None, [rec.metadata.get("ignored_variables"), *ignored]))
    rec.metadata["format"] = "MATLAB v7.3 (HDF5)" if matlab else "HDF5"
    return rec.choose(columns, units)
