"""Excel workbooks (.xlsx, .xlsm; openpyxl, `pip install fluxcal[excel]`).

A sheet is read as the text table it shows: each row a line, its cells joined by tabs (numbers as stored,
dates and times in ISO 8601), then parsed exactly as a tab-delimited file — a header of names
(units in brackets, or a row of units under it), comment or key/value rows above, time stamps, text
columns, bad rows named or skipped (fluxcal.io.formats). The sheet is the first one holding a table of
numbers; the others are named in metadata["other_sheets"]. Messages name the workbook, the sheet and
the row. The legacy binary .xls is refused with the remedy (save as .xlsx or CSV).
"""
from __future__ import annotations

import datetime as _dt
from pathlib import Path

from .csv import readable_file, _is_number
from .recording import Recording


EXCEL_ERRORS = {"#N/A", "#DIV/0!", "#VALUE!", "#REF!", "#NAME?", "#NUM!", "#NULL!", "#GETTING_DATA", "#SPILL!",
                "#CALC!"}


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, str) and value.strip() in EXCEL_ERRORS:  # not a '#' comment: a bad cell
        return f"Excel error {value.strip()}"
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (_dt.datetime, _dt.date, _dt.time)):
        return value.isoformat()
    return str(value).replace("\t", " ").replace("\r", " ").replace("\n", " ")


def _sheet_lines(sheet) -> list:
    """The sheet's rows as tab-joined lines: empty columns to the left of the table dropped, and single-cell
    rows above its first row of several cells (a title, a note) made comments."""
    rows = []
    for row in sheet.iter_rows(values_only=True):
        cells = [_cell(v) for v in row]
        while cells and not cells[-1]:
            cells.pop()
        rows.append(cells)
    filled = [r for r in rows if r]
    left = min((next(k for k, c in enumerate(r) if c) for r in filled), default=0)
    lines, table = [], False
    for cells in rows:
        cells = cells[left:]
        table = table or sum(bool(c) for c in cells) > 1
        lines.append("# " + " ".join(c for c in cells if c) if not table and cells else "\t".join(cells))
    return lines


def _numeric_rows(lines) -> int:
    return sum(sum(_is_number(c) for c in line.split("\t")) >= 3 for line in lines[:200])


def read_xlsx(path, columns=None, units: str | None = None, bad_lines: str = "error") -> Recording:
    path = readable_file(path)
    try:
        import openpyxl
    except ImportError:
        raise ValueError(f"{path}: an Excel workbook; reading it needs openpyxl (pip install 'fluxcal[excel]'), "
                         "or save the sheet as CSV") from None
    try:
        book = openpyxl.load_workbook(path, read_only=True, data_only=True)
    except Exception as exc:  # a damaged zip or XML: openpyxl raises many kinds
        raise ValueError(f"{path}: not a readable Excel workbook ({type(exc).__name__}: {exc})") from None
    try:
        sheets = {name: _sheet_lines(book[name]) for name in book.sheetnames}
    finally:
        book.close()
    name = next((n for n, lines in sheets.items() if _numeric_rows(lines) > 0), None)
    if name is None:
        raise ValueError(f"{path}: no sheet holds rows of numbers (sheets: {', '.join(sheets) or 'none'})")
    from .formats import read_table_lines

    rec = read_table_lines(sheets[name], f"{path}, sheet {name!r}", columns, units, bad_lines, "row")
    rec.metadata["sheet"] = name
    others = [n for n in sheets if n != name]
    if others:
        rec.metadata["other_sheets"] = ", ".join(others)
    return rec
