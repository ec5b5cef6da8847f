"""Parquet recordings via pyarrow (the optional extra `fluxcal[parquet]`).

Layout written by fluxcal: one float64 column per recording column; the schema metadata key
`fluxcal` holds the JSON description (column order, units, metadata), and each field's own metadata
carries `unit`, so other tools (pandas, Polars, DuckDB) see the units too.

Files fluxcal did not write: numeric columns (integers, floats, booleans) become recording columns,
timestamps become seconds since the epoch (unit "s"); columns of other types (strings, lists) are
listed in metadata["ignored_columns"]. The magnetometer is mx,my,mz or x,y,z, or `columns`.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .csv import readable_file
from .npz import header, parse_header
from .recording import Recording

META_KEY = b"fluxcal"


def _pyarrow():
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise ValueError("Parquet needs pyarrow: pip install 'fluxcal[parquet]' (or pip install pyarrow)") from None
    return pyarrow, pyarrow.parquet


def write_parquet(path, rec: Recording) -> Path:
    pa, pq = _pyarrow()
    path = Path(path)
    fields = [pa.field(name, pa.float64(), metadata={"unit": rec.units[name]} if rec.units.get(name) else None)
              for name in rec.columns]
    schema = pa.schema(fields, metadata={META_KEY: json.dumps(header(rec)).encode()})
    table = pa.Table.from_arrays([pa.array(np.asarray(v, dtype=float)) for v in rec.columns.values()], schema=schema)
    pq.write_table(table, path)
    return path


def read_parquet(path, columns=None, units: str | None = None) -> Recording:
    """Read a Parquet recording; a truncated or corrupt file is a ValueError naming it."""
    pa, pq = _pyarrow()
    path = readable_file(path)
    try:
        table = pq.read_table(path)
    except FileNotFoundError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except Exception as exc:  # ArrowInvalid, OSError from the decoder… all mean a damaged file
        raise ValueError(f"{path}: not a readable Parquet file (truncated or corrupt? "
                         f"{type(exc).__name__}: {exc})") from None
    schema_meta = table.schema.metadata or {}
    info = parse_header(schema_meta[META_KEY].decode(), str(path)) if META_KEY in schema_meta else None
    cols, unit_map, ignored = {}, {}, []
    for field, column in zip(table.schema, table.columns):
        unit = (field.metadata or {}).get(b"unit", b"").decode()
        if pa.types.is_timestamp(field.type):
            seconds = column.cast(pa.int64()).to_numpy(zero_copy_only=False) / _per_second(field.type.unit)
            cols[field.name], unit = seconds.astype(float), "s"
        elif pa.types.is_integer(field.type) or pa.types.is_floating(field.type) or pa.types.is_boolean(field.type):
            # nulls become NaN, so Recording.samples() reports the row instead of silently dropping it
            cols[field.name] = column.cast(pa.float64()).to_numpy(zero_copy_only=False)
        else:
            ignored.append(f"{field.name} ({field.type})")
            continue
        if unit:
            unit_map[field.name] = unit
    metadata = {}
    if info is not None:
        cols = {c: cols[c] for c in info["columns"] if c in cols}
        unit_map.update(info.get("units", {}))
        metadata.update(info.get("metadata", {}))
    if ignored:
        metadata["ignored_columns"] = "; ".join(ignored)
    return Recording(columns=cols, units=unit_map, metadata=metadata, source=str(path)).choose(columns, units)


def _per_second(unit: str) -> float:
    return {"s": 1.0, "ms": 1e3, "us": 1e6, "ns": 1e9}[unit]
