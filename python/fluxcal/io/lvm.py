"""LabVIEW measurement files (.lvm, the text format of LabVIEW's Write To Measurement File).

A file header (`LabVIEW Measurement`, key-tab-value lines, `***End_of_Header***`), then one segment or more: a segment
header (Channels, Samples, Y_Unit_Label, X_Dimension …, `***End_of_Header***`), a row of column names (`X_Value`, the
channels' names, often a last `Comment`) and the data rows. Read here as one table: the segments' rows one after the
other (they must name the same channels), `X_Value` as `time` when X_Dimension says Time (a second X column per
channel, X_Columns Multi, is left out), each channel's Y_Unit_Label as its unit, and the file's Separator and
Decimal_Separator honoured. Line numbers in messages are the file's.
"""
from __future__ import annotations

from pathlib import Path

from .recording import Recording

END = "***End_of_Header***"
# the keys a segment's header starts with (LabVIEW writes Channels first; Notes and the test keys may come before)
SEGMENT_KEYS = {"Channels", "Samples", "Date", "Time", "Y_Unit_Label", "X_Dimension", "X0", "Delta_X", "Notes",
                "Test_Name", "Test_Numbers", "Test_Series", "UUT_Name", "UUT_Serial_Number", "Comment", END}


def looks_like_lvm(head: bytes) -> bool:
    return head.lstrip(b"\xef\xbb\xbf").startswith(b"LabVIEW Measurement")


def _fields(line: str, separator: str) -> list:
    return [c.strip() for c in line.rstrip("\r\n").split(separator)]


def read_lvm(path, columns=None, units: str | None = None, bad_lines: str = "error") -> Recording:
    """A LabVIEW .lvm file as one Recording (module docstring); ValueError naming the file and line when it is
    not one fluxcal can read (no segment, segments naming different channels)."""
    from .csv import read_text
    from .formats import read_table_lines

    path = Path(path)
    lines = read_text(path).splitlines()
    ends = [k for k, line in enumerate(lines) if line.strip().startswith(END)]
    if not ends:
        raise ValueError(f"{path}: a LabVIEW measurement file without '{END}': cut short?")
    # the file's separator (its Separator line, Tab or Comma) already parts the header's keys from their values
    separator = "," if any(line.startswith("Separator,Comma") for line in lines[:ends[0]]) else "\t"
    settings = {}
    for line in lines[:ends[0]]:
        key, _, value = line.partition(separator)
        settings[key.strip()] = value.strip().rstrip(separator)
    decimal_comma = settings.get("Decimal_Separator", ".") == ","
    x_columns = settings.get("X_Columns", "One")
    segments = ends[1:]
    if not segments:
        raise ValueError(f"{path}: a LabVIEW measurement file with its file header only, no data segment (line "
                         f"{ends[0] + 1} is the header's end)")
    names, rows, cut = None, [], None
    for s, end in enumerate(segments):
        header = {}
        for line in lines[(ends[0] if s == 0 else segments[s - 1]) + 1:end]:
            cells = _fields(line, separator)
            if cells and cells[0]:
                header[cells[0]] = cells[1:]
        k = end + 1
        while k < len(lines) and not lines[k].strip():
            k += 1
        if k >= len(lines):
            raise ValueError(f"{path}, line {end + 1}: a segment header with no column names or data after it")
        these = _fields(lines[k], separator)
        keep = [j for j, name in enumerate(these) if name and name != "Comment"
                and not (name == "X_Value" and (x_columns == "No" or j > 0))]
        labelled = [these[j] for j in keep]
        if names is None:
            names, keep_first, first_names = labelled, keep, these
            unit_of = header.get("Y_Unit_Label", [])
            time = header.get("X_Dimension", [""])[:1] == ["Time"]
        elif labelled != names:
            raise ValueError(f"{path}, line {k + 1}: segment {s + 1} names the channels {', '.join(labelled)}, the "
                             f"first segment {', '.join(names)}: fluxcal reads segments of the same channels")
        end_of_data = segments[s + 1] if s + 1 < len(segments) else len(lines)
        # a next segment's header starts above its own ***End_of_Header***: at its first key (a garbled data row is
        # no key: it stays, to be named by its line — a review: taken for a header, it had dropped the rest of its
        # segment, unsaid)
        for line_no in range(k + 1, end_of_data):
            line = lines[line_no]
            cells = _fields(line, separator)
            if cells and cells[0] in SEGMENT_KEYS:
                if s + 1 == len(segments):
                    cut = line_no + 1  # a segment header with no end: the file was cut inside it
                break
            if not line.strip():
                continue
            values = [cells[j] if j < len(cells) else "" for j in keep]
            rows.append((line_no + 1, "\t".join(v.replace(",", ".") if decimal_comma else v for v in values)))
    if not rows:
        raise ValueError(f"{path}: a LabVIEW measurement file with no data rows")
    heads = []
    for j, name in zip(keep_first, names):
        if name == "X_Value":
            heads.append("time [s]" if time else "x")
            continue
        channel = sum(c not in ("X_Value", "Comment", "") for c in first_names[:j])  # Y_Unit_Label: one per channel
        unit = unit_of[channel] if 0 <= channel < len(unit_of) else ""
        heads.append(f"{name} [{unit}]" if unit and unit not in ("-", "") else name)
    # each row at its own line of the table, blank lines between (passed over): the lines said in messages are the
    # file's, across segments and blank lines too
    table = [""] * rows[-1][0]
    table[0] = "\t".join(heads)
    for line_no, row in rows:
        table[line_no - 1] = row
    rec = read_table_lines(table, str(path), columns, units, bad_lines)
    rec.metadata["format"] = "LabVIEW measurement (.lvm)" + (f", {len(segments)} segments" if len(segments) > 1
                                                             else "")
    if cut is not None:
        import warnings

        rec.metadata["cut_short"] = f"line {cut}: a segment header with no end (the file cut short?)"
        warnings.warn(f"{path}, line {cut}: a segment header with no {END}: the file was cut short? The rows "
                      "before it are read", UserWarning, stacklevel=2)
    for key in ("Date", "Time", "Operator", "Description", "Project"):
        if settings.get(key):
            rec.metadata.setdefault(f"lvm_{key.lower()}", settings[key])
    return rec


def _numberish(cell: str, decimal_comma: bool) -> bool:
    try:
        float(cell.replace(",", ".") if decimal_comma else cell)
        return True
    except ValueError:
        return False
