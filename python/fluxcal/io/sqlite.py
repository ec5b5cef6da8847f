"""SQLite databases (Python's own sqlite3; nothing to install).

Some loggers and phone apps keep their samples in an SQLite file, one table per sensor or one table for
all. A table is read as the text table it holds: its column names the header, each row a line (NULL an
empty cell, a BLOB a bad cell), then parsed exactly as a tab-delimited file (fluxcal.io.formats): units in
brackets, time stamps, text columns, bad rows named or skipped. The table is the one named by
`columns` when that is a table's name (`--columns samples`), else the first that holds a magnetometer's
columns, else the first with rows of three or more numbers; the others are named in
metadata["other_tables"]. Messages name the database, the table and the row. The file is opened read-only.
A ROS 2 bag's storage file (tables `topics` and `messages`) is refused with the remedy: read its folder.
"""
from __future__ import annotations

import sqlite3
from pathlib import Path

from .csv import readable_file, _is_number
from .recording import Recording


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return "BLOB"  # not a number: a bad cell, named with its row
    if isinstance(value, float):
        return repr(value)
    return str(value).replace("\t", " ").replace("\r", " ").replace("\n", " ")


def _tables(db) -> list:
    rows = db.execute("SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%' "
                      "ORDER BY rowid").fetchall()
    return [r[0] for r in rows]


def _quoted(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


def _numeric(db, table: str) -> bool:
    rows = db.execute(f"SELECT * FROM {_quoted(table)} LIMIT 50").fetchall()
    return any(sum(_is_number(_cell(v)) for v in row) >= 3 for row in rows)


def read_sqlite(path, columns=None, units: str | None = None, bad_lines: str = "error") -> Recording:
    path = readable_file(path)
    try:
        db = sqlite3.connect(f"file:{path.resolve()}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        raise ValueError(f"{path}: not a readable SQLite database ({exc})") from None
    try:
        try:
            tables = _tables(db)
        except sqlite3.DatabaseError as exc:  # a damaged or truncated file
            raise ValueError(f"{path}: not a readable SQLite database ({exc})") from None
        if {"topics", "messages"} <= set(tables):
            raise ValueError(f"{path}: a ROS 2 bag's storage file without its folder's metadata.yaml; read the "
                             "bag folder")
        named = columns if isinstance(columns, str) and columns in tables else None
        if named is not None:
            name, columns = named, None
        else:
            numeric = [t for t in tables if _numeric(db, t)]
            if not numeric:
                raise ValueError(f"{path}: no table holds rows of numbers (tables: {', '.join(tables) or 'none'})")
            name = next((t for t in numeric if _has_magnetometer(db, t)), numeric[0])
        cursor = db.execute(f"SELECT * FROM {_quoted(name)}")
        header = "\t".join(d[0] for d in cursor.description)
        lines = [header] + ["\t".join(_cell(v) for v in row) for row in cursor]
    except sqlite3.DatabaseError as exc:
        raise ValueError(f"{path}: not a readable SQLite database ({exc})") from None
    finally:
        db.close()
    if len(lines) == 1:
        raise ValueError(f"{path}, table {name!r}: no rows")
    from .formats import read_table_lines

    # a header line first: database rows are lines 2, 3, … of the text, so row k of the table is line k + 1
    rec = read_table_lines(lines, f"{path}, table {name!r}", columns, units, bad_lines, "row", offset=-1)
    rec.metadata["table"] = name
    others = [t for t in tables if t != name]
    if others:
        rec.metadata["other_tables"] = ", ".join(others)
    return rec


def _has_magnetometer(db, table: str) -> bool:
    from .columns import find_magnetometer

    names = [d[0] for d in db.execute(f"SELECT * FROM {_quoted(table)} LIMIT 0").description]
    try:
        return find_magnetometer(names, table) is not None
    except ValueError:  # several triples: still a magnetometer's table
        return True
