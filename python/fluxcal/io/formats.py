"""read_recording / write_recording: every recording format fluxcal knows, chosen by content.

Reading looks at the bytes, not the name (a file's extension is only a hint in messages):

    PK\\x03\\x04 (zip)              → NumPy .npz            (fluxcal.io.npz), or with xl/workbook.xml an
                                     Excel .xlsx/.xlsm      (fluxcal.io.excel; needs fluxcal[excel])
    \\x93NUMPY                      → NumPy .npy (one N×3 array)
    "MATLAB 5.0 MAT-file" header   → MATLAB .mat v5/v7     (fluxcal.io.matlab)
    a MAT v4 matrix header (.mat)  → MATLAB .mat v4        (fluxcal.io.matlab: SciPy reads it too)
    HDF5, "MATLAB 7.3" header      → MATLAB v7.3 / HDF5    (fluxcal.io.hdf5; needs fluxcal[hdf5])
    PAR1                           → Parquet               (fluxcal.io.parquet)
    \\xA3\\x95                      → ArduPilot DataFlash .bin (fluxcal.io.drone; needs fluxcal[drone])
    ULog\\x01\\x12\\x35             → PX4 ULog .ulg            (fluxcal.io.drone; needs fluxcal[drone])
    text with FMT, <n> lines first → ArduPilot DataFlash text .log (fluxcal.io.drone; needs fluxcal[drone])
    #ROSBAG V2.0, or a folder with
    metadata.yaml (.db3/.mcap)     → ROS 1 / ROS 2 bag      (fluxcal.io.rosbag; needs fluxcal[ros])
    SQLite format 3 (not a bag)    → a database table       (fluxcal.io.sqlite; --columns TABLE picks one)
    " Format  IAGA-2002  |" first  → geomagnetic observatory data (fluxcal.io.iaga: X, Y, Z in nT from XYZ, HDZ,
                                     DHI or HEZ)
    "LabVIEW Measurement" first    → LabVIEW .lvm text     (fluxcal.io.lvm: segments joined, X_Value as time,
                                     Y_Unit_Label as units)
    text starting with { or [      → JSON readings         (fluxcal.io.real: fluxcal's layout or shot triples;
    (not a log tag, `[MAG] X: …`)    fluxcal.io.jsonrecords: JSON Lines, a list of records, a columns/data table)
    text of `$TYPE,…*hh` lines     → NMEA-style IMU sentences ($VNYMR…, fluxcal.io.sentences)
    text of `label: number` pairs  → a serial monitor's capture, `Mag X: 1.2 Y: 3.4 Z: 5.6 uT` or
                                     `mx=1.2,my=3.4,mz=5.6` (fluxcal.io.labelled)
    other text                     → a table. A serial monitor's clock before each line (`15:02:11.143 -> `,
                                     `[2026-11-29 15:02:11.123] `) becomes the column `time`. Its delimiter is
                                     that of the first data line: tab, else comma, else semicolon, else
                                     whitespace. Then:
        `name,number` lines before the header → key,value preamble (QMC5883L logger; Fs gives t)
        a header of names                     → fluxcal CSV (fluxcal.io.csv), any of those delimiters
        numbers on the first line             → header-less: a comment line just above that names every
                                                 column (`# t mx my mz`) is the header; else `columns` names every column, else the
                                                 airborne 10-column layout if it fits, else an error
                                                 asking for --columns (one name per column); text lines
                                                 above the rows --columns names are a banner (the preamble),
                                                 a partial line of numbers is a bad line

`columns` is also how to pick the magnetometer: three names (or "a,b,c") select columns; a single name
picks the N×3 matrix variable of a .mat/.npz; for a flight log it may name the compass instance
("MAG[1]", "sensor_mag[1]"), optionally followed by three column names (see fluxcal.io.drone).
`units` states the magnetometer unit when the file does not.
Writing goes by extension: .csv .npz .mat .parquet/.pq .json.
"""
from __future__ import annotations

import re
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

from .csv import (COMMA_GIVEN, is_processing_row, is_units_row, SKIP_HINT, _DECIMAL_COMMA, _decimal_comma_columns, readable_file, _is_number, comment_text, data_cells, data_lines, decimal_points, is_comment, parse_csv,
                  listing, read_lines, read_text, warn_skipped, write_csv, OTHER_WRITERS)
from .recording import Recording, instance_pick

WRITERS = (".csv",) + OTHER_WRITERS


def sniff(path) -> str:
    """The format of a file by its content: "npz", "npy", "xlsx", "xls", "mat", "hdf5", "parquet", "dataflash",
    "dataflash_text", "ulog", "rosbag" (also a ROS 2 bag folder), "iaga2002", "lvm", "json" or "text"."""
    path = Path(path)
    from .rosbag import bag_path

    if path.is_dir():
        if bag_path(path) is not None:
            return "rosbag"
        raise ValueError(f"{path}: a folder, not a recording (a ROS 2 bag folder holds a metadata.yaml)")
    readable_file(path)  # a named pipe would block the read below
    try:
        with path.open("rb") as f:
            head = f.read(128)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "xlsx" if _zip_holds(path, "xl/workbook.xml") else "npz"
    if head.startswith(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"):  # OLE2: a legacy .xls (or another Office file)
        return "xls"
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head.startswith(b"MATLAB 7.3") or (head.startswith(b"MATLAB") and b"HDF5" in head):
        return "hdf5"
    if head.startswith(b"MATLAB") or (path.suffix.lower() == ".mat" and _mat_v4(head)):
        return "mat"
    if head.startswith(b"\x89HDF"):
        return "hdf5"
    if head.startswith(b"PAR1"):
        return "parquet"
    if head.startswith(b"#ROSBAG V2.0\n") or (head.startswith((b"SQLite format 3\x00", b"\x89MCAP"))
                                               and bag_path(path) is not None):
        return "rosbag"
    if head.startswith(b"SQLite format 3\x00"):
        return "sqlite"
    if head.startswith(b"\x89MCAP"):
        raise ValueError(f"{path}: a ROS 2 bag's storage file without its folder's metadata.yaml; read the bag "
                         "folder")
    if head.startswith(b"\xa3\x95"):  # every DataFlash message starts with these two bytes
        return "dataflash"
    if head.startswith(b"ULog\x01\x12\x35"):
        return "ulog"
    if re.search(rb"(?:^|\n)\s*FMT, ?\d", head.lstrip(b"\xef\xbb\xbf")):  # a text log's FMT lines come first
        return "dataflash_text"
    from .iaga import looks_like_iaga
    from .lvm import looks_like_lvm

    if looks_like_iaga(head):
        return "iaga2002"
    if looks_like_lvm(head):
        return "lvm"
    text = head.decode("utf-16", errors="ignore").encode() if head.startswith((b"\xff\xfe", b"\xfe\xff")) else head
    text = text.lstrip(b"\xef\xbb\xbf \t\r\n")
    # not "[12:30:01] …", nor a log line's tag ("[MAG] X: 1 …", "[1] mx=…"): text after the ']' that JSON cannot have
    if text[:1] == b"{" or (text[:1] == b"[" and not re.match(rb"\[\s*\d{1,4}[-:/]\d", text)
                            and not re.match(rb"\[[^\[\]{}\"\r\n]*\][ \t]*[^\s,\]}]", text)):
        return "json"
    if not head:
        raise ValueError(f"{path}: empty file")
    return "text"


def _mat_v4(head: bytes) -> bool:
    """Whether `head` starts as a MAT v4 file (MATLAB's save -v4, SciPy's savemat(format="4"), older instruments'
    software): no text header, but a first matrix header of five int32 — type MOPT (M 0–1 byte order, O 0, P 0–5
    the number type, T 0–2), rows, columns, imaginary flag 0 or 1, the name's length with its NUL. Had been refused
    as "does not start as one"."""
    import struct

    if len(head) < 20:
        return False
    for order in "<>":
        mopt, rows, cols, imag, namelen = struct.unpack(order + "5i", head[:20])
        m, o, p, t = mopt // 1000, mopt // 100 % 10, mopt // 10 % 10, mopt % 10
        if (0 <= mopt < 2000 and m == (0 if order == "<" else 1) and o == 0 and p <= 5 and t <= 2
                and rows >= 0 and cols >= 0 and imag in (0, 1) and 1 < namelen <= 64):
            return True
    return False


def _zip_holds(path: Path, member: str) -> bool:
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            return member in z.namelist()
    except (zipfile.BadZipFile, OSError):
        return False


def read_recording(path, columns=None, units: str | None = None, bad_lines: str = "error",
                   decimal: str | None = None, thousands: str | None = None) -> Recording:
    """Read any recording format fluxcal knows (module docstring); errors name the file, and for text
    formats the line and column.
    `bad_lines` (text tables with a header): "error" stops at a line with the wrong number of fields or a
    non-number, naming line and column; "skip" leaves such lines out, lists them in
    metadata["skipped_lines"] and warns of them (a UserWarning; fluxcal.io.csv.quiet_skipped silences it).
    `decimal`/`thousands` (labelled text logs, `X: 1,234`, and tables delimited by ';' or tab): decimal=','
    reads a comma between digits as a decimal comma (and points before it as thousands groups, 45.199,6),
    thousands=',' (or decimal='.') as a thousands separator, when no number in the file settles it (see
    fluxcal.io.labelled.read_labelled, fluxcal.io.csv.decimal_points); an error for other formats."""
    return warn_skipped(_read_recording(path, columns, units, bad_lines, decimal, thousands))


def _read_recording(path, columns, units, bad_lines: str, decimal, thousands) -> Recording:
    path = Path(path)
    if decimal is not None or thousands is not None:
        from . import labelled, real, sentences

        lines = read_text(path).splitlines() if sniff(path) == "text" else []
        start = real._skip_comments(lines)
        if start < len(lines) and not sentences.looks_like_sentences(lines, start):
            if labelled.looks_labelled(lines, start):
                return labelled.read_labelled(path, columns=columns, units=units, bad_lines=bad_lines,
                                              decimal=decimal, thousands=thousands)
            if _delimiter(lines, start) in (";", "\t"):  # a spreadsheet export: the comma's reading is given
                given = COMMA_GIVEN.set(labelled.stated_comma(decimal, thousands))
                try:
                    return _read_table(path, columns, units, bad_lines)
                finally:
                    COMMA_GIVEN.reset(given)
        raise ValueError(f"{path}: decimal= and thousands= apply to labelled text logs (X: 1,234) and to tables "
                         "delimited by ';' or tab, not to this file (a comma-delimited table's commas are its "
                         "delimiters)")
    kind = sniff(path)
    if kind in ("dataflash", "dataflash_text"):
        from .drone import read_dataflash

        return read_dataflash(path, columns=columns, units=units)
    if kind == "ulog":
        from .drone import read_ulog

        return read_ulog(path, columns=columns, units=units)
    if kind == "rosbag":
        from .rosbag import read_rosbag

        return read_rosbag(path, columns=columns, units=units)
    if kind == "xlsx":
        from .excel import read_xlsx

        return read_xlsx(path, columns=columns, units=units, bad_lines=bad_lines)
    if kind == "sqlite":
        from .sqlite import read_sqlite

        return read_sqlite(path, columns=columns, units=units, bad_lines=bad_lines)
    if kind == "xls":
        raise ValueError(f"{path}: a legacy binary Excel (.xls) or other OLE2 Office file; save the sheet as .xlsx "
                         "or CSV")
    single = isinstance(columns, str) and "," not in columns and columns.strip() != ""
    if kind in ("hdf5", "npz", "npy", "mat"):
        matrix, cols = (columns, None) if single else (None, columns)
        if kind == "hdf5":
            from .hdf5 import read_hdf5

            return read_hdf5(path, columns=cols, units=units, matrix=matrix)
        if kind == "mat":
            from .matlab import read_mat

            return read_mat(path, columns=cols, units=units, matrix=matrix)
        from .npz import read_npz

        return read_npz(path, columns=cols, units=units, matrix=matrix)
    if kind == "parquet":
        from .parquet import read_parquet

        return read_parquet(path, columns=columns, units=units)
    if kind == "iaga2002":
        from .iaga import read_iaga2002

        return read_iaga2002(path, columns=columns, units=units, bad_lines=bad_lines)
    if kind == "lvm":
        from .lvm import read_lvm

        return read_lvm(path, columns=columns, units=units, bad_lines=bad_lines)
    if kind == "json":
        from .real import read_json_recording

        return read_json_recording(path, columns=columns, units=units, bad_lines=bad_lines)
    return _read_table(path, columns, units, bad_lines)


def read_table_lines(lines, where: str, columns, units, bad_lines: str = "error", word: str = "line",
                     offset: int = 0) -> Recording:
    """Text lines made from a source that is not text (a sheet, a database table) parsed as a table file;
    messages and metadata["skipped_lines"] name `where` and its rows (`word` n, n = the line + `offset`)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        text = Path(tmp) / "table.tsv"
        text.write_text("\n".join(lines) + "\n", encoding="utf-8")

        def renamed(message: str) -> str:
            message = re.sub(re.escape(str(text)) + r", line (\d+)",
                             lambda m: f"{where}, {word} {int(m.group(1)) + offset}", message)
            return message.replace(str(text), where)

        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                rec = _read_table(text, columns, units, bad_lines)
        except ValueError as exc:
            raise ValueError(renamed(str(exc))) from None
    for w in caught:  # said of `where`, not of the temporary file
        warnings.warn(renamed(str(w.message)), w.category, stacklevel=2)
    skipped = rec.metadata.get("skipped_lines")
    if skipped:
        rec.metadata["skipped_lines"] = re.sub(r"(?:(?<=: )|(?<=; ))(\d+) \(",
                                               lambda m: f"{word} {int(m.group(1)) + offset} (", skipped)
    rec.source = where
    return rec


def _read_table(path: Path, columns, units, bad_lines: str = "error") -> Recording:
    from . import real

    lines = read_lines(path)
    start = real._skip_comments(lines)
    if start >= len(lines):
        raise ValueError(f"{path}: no header line and no data (only comments or blank lines)")
    from . import labelled, sentences

    if sentences.looks_like_sentences(lines, start):
        return sentences.read_sentences(path, columns=columns, units=units, bad_lines=bad_lines)
    if labelled.looks_labelled(lines, start):
        return labelled.read_labelled(path, columns=columns, units=units, bad_lines=bad_lines)
    if _clock_lines(lines, start):  # the Arduino IDE's `hh:mm:ss.mmm -> ` (or `[date time] `) before each table line
        return _read_clocked_table(path, lines, columns, units, bad_lines)
    delimiter = _delimiter(lines, start)
    if real.preamble_length(lines, start, delimiter) > 0:
        return real.read_preamble_csv(path, columns=columns, units=units, delimiter=delimiter, bad_lines=bad_lines)
    titled = _title_lines(lines, start, delimiter)
    if titled:  # a sketch's banner above its header (Arduino's "Magnetic Field in uT", then "X Y Z")
        rec = parse_csv(path, lines, delimiter, preamble_lines=titled, bad_lines=bad_lines)
        rec.metadata["preamble"] = listing([f"line {k + 1}: {lines[k].strip()}" for k in range(start, start + titled)
                                            if lines[k].strip()])
        return rec.choose(columns, units)
    given = instance_pick(columns, str(path))[0]  # the column names (not a compass's pick, I=1)
    lead = _lead_lines(lines, start, delimiter, len(given)) if given is not None and len(given) > 1 else 0
    if lead:  # a banner or a partial line above a header-less table whose columns --columns names
        return _read_after_lead(path, lines, start, lead, columns, len(given), units, bad_lines, delimiter)
    if given is None:
        _banner_above_headerless(path, lines, start, delimiter)
    first = [c.strip() for c in decimal_points(lines[start:start + 400], 0, delimiter)[0][0].split(delimiter)]
    numbers = sum(_is_number(c) for c in first)
    # a row of mostly numbers with a text cell or two (ROS `rostopic echo -p`: frame_id) is data, not a header,
    # when the comment above names every column (`%time,field.header.seq,…`)
    header = _commented_header(lines, start, delimiter, len(first)) if 2 * numbers >= len(first) else None
    if numbers == len(first) or header is not None:
        if header is not None and (given is None or set(given) <= set(header[1])):  # names picked from it
            line_no, names, cells = header
            # read as if the comment were the header line: units, '# key: value' lines above, bad lines as there
            body = lines[:line_no - 1] + [(delimiter or " ").join(cells)] + lines[line_no:]
            rec = parse_csv(path, body, delimiter, bad_lines=bad_lines)
            rec.metadata["header"] = f"the comment on line {line_no}"
            return rec.choose(columns, units)
        names = given
        if names is not None and (len(names) == len(first) or len(names) != 3):
            return real.read_headerless(path, names=names, units=units, delimiter=delimiter)
        # no names, or three: the magnetometer of a recognised layout
        return real.read_headerless(path, columns=columns, units=units, delimiter=delimiter)
    return parse_csv(path, lines, delimiter, bad_lines=bad_lines).choose(columns, units)


# a serial monitor's clock before a line: the Arduino IDE's `15:02:11.143 -> `, a terminal's `[2026-11-29 15:02:11.123] `
_CLOCK_TIME = r"(?:\d{4}-\d{1,2}-\d{1,2}[ T])?\d{1,2}:\d{2}:\d{2}(?:[.,]\d+)?"
_CLOCK_PREFIX = re.compile(rf"^\s*(?:\[({_CLOCK_TIME})\]|({_CLOCK_TIME})\s*->)\s*")


def _clock_lines(lines, start: int) -> bool:
    """Whether (nearly) every one of the first data lines starts with a serial monitor's clock (_CLOCK_PREFIX)."""
    sample = data_lines(lines, start, 50)
    return len(sample) >= 2 and sum(bool(_CLOCK_PREFIX.match(line)) for line in sample) >= 0.9 * len(sample)


def _read_clocked_table(path: Path, lines, columns, units, bad_lines: str) -> Recording:
    """A table printed through a serial monitor with its clock on each line: the table read without the clocks
    (lines keep their numbers), the clock added as the column `time` in seconds (`clock` when the table has its
    own time), as fluxcal.io.labelled does for labelled lines."""
    from .csv import _timestamps

    stamps, bare = {}, []
    for n, line in enumerate(lines, 1):
        m = _CLOCK_PREFIX.match(line)
        if m:
            stamps[n] = m.group(1) or m.group(2)
        bare.append(line[m.end():] if m else line)
    rec = read_table_lines(bare, str(path), columns, units, bad_lines)
    rows = rec.line_numbers if rec.line_numbers is not None else []
    seconds, first = _timestamps([stamps.get(int(n), "") for n in rows])
    name = "clock" if rec._time_column() is not None else "time"  # the table's own (millis, t, …) wins
    if seconds is not None and np.isfinite(seconds).all() and name not in rec.columns:
        rec.columns[name], rec.units[name] = seconds, "s"
        rec.metadata[f"{name}_start"] = first
    return rec


def _cells(line: str, delimiter) -> list:
    """A table line's cells; a delimiter ending the line (Arduino's `x,y,z,`) makes no field."""
    line = line.rstrip()
    if delimiter and delimiter.strip() and line.endswith(delimiter):
        line = line[:-len(delimiter)]
    return [c.strip() for c in (line.split(delimiter) if delimiter else line.split())]


def _numberish(cell: str, delimiter) -> bool:
    """A number; a decimal comma (59,5) is one too in a ';' or tab table."""
    return _is_number(cell) or (delimiter in (";", "\t") and bool(_DECIMAL_COMMA.match(cell)))


def _lead_lines(lines, start: int, delimiter, count: int) -> int:
    """How many lines before the first row of `count` numbers (a header-less table, `count` the names --columns
    gives) do not fit it: a start-up banner ("MPU9250 init OK"), the partial line a capture starts with
    ("3.45 -12"). 0 when the first line fits, when a line of `count` names (a header) comes first, or when no
    two rows that fit follow within 30 lines."""
    body = [k for k in range(start, min(len(lines), start + 30)) if lines[k].strip() and not is_comment(lines[k])]

    def fits(k):
        c = _cells(lines[k], delimiter)
        return len(c) == count and all(_numberish(x, delimiter) for x in c)

    for n, k in enumerate(body[:-1]):
        if len(_cells(lines[k], delimiter)) == count and not fits(k):
            return 0  # a header (or a garbled row): not this case
        if fits(k) and fits(body[n + 1]):
            return k - start
    return 0


def _banner_above_headerless(path: Path, lines, start: int, delimiter) -> None:
    """Refuse, naming both, a banner of free text above a table of numbers without a header: the banner had been
    taken for the header ("line 2: 3 fields, the header has 1 … garbled line?"). --columns reads such a file (the
    banner kept as its preamble)."""
    from .csv import _header_cells

    body = [_cells(lines[k], delimiter) for k in range(start, min(len(lines), start + 30))
            if lines[k].strip() and not is_comment(lines[k])]
    widths = Counter(len(c) for c in body if len(c) > 1 and all(_numberish(x, delimiter) for x in c))
    if not widths:
        return
    count = widths.most_common(1)[0][0]
    lead = _lead_lines(lines, start, delimiter, count)
    lead_cells = [_header_cells(lines[k].strip(), delimiter) for k in range(start, start + lead)]  # (quotes kept)
    # a banner is one field of text: a line of fewer names than the columns is a short header, said as before, and
    # a line of numbers the partial line a capture starts with
    if lead and all(len(c) <= 1 for c in lead_cells) and any(
            not all(_numberish(x, delimiter) for x in c) for c in lead_cells if c and c != [""]):
        sep = {"\t": "tab", ",": "comma", None: "whitespace"}.get(delimiter, repr(delimiter))
        example = ",".join(["mx", "my", "mz"][:count] if count <= 3 else ["t", "mx", "my", "mz"][:count] +
                           [f"c{k}" for k in range(5, count + 1)])
        raise ValueError(f"{path}, line {start + lead + 1}: {count} {sep}-separated numbers and no header (line "
                         f"{start + 1} above them, {lines[start].strip()[:60]!r}, is text: a banner); name the columns "
                         f"with --columns (Python: columns=; one name per column, e.g. {example}) — the banner is then "
                         "kept as the preamble — or add a header line under it")


def _read_after_lead(path: Path, lines, start: int, lead: int, columns, count: int, units, bad_lines: str,
                     delimiter):
    """The header-less table under `lead` lines that do not fit it (_lead_lines): lines of text are the preamble,
    kept in metadata["preamble"] (as fluxcal.io.labelled keeps a banner); lines of numbers (a partial first
    line) are bad lines: an error naming the first, or left out and listed with bad_lines="skip"."""
    text, cut = [], []
    for k in range(start, start + lead):
        c = _cells(lines[k], delimiter) if lines[k].strip() and not is_comment(lines[k]) else []
        if c:
            (cut if all(_numberish(x, delimiter) for x in c) else text).append(k)
    if cut and bad_lines != "skip":
        k = cut[0]
        raise ValueError(f"{path}, line {k + 1}: {len(_cells(lines[k], delimiter))} fields where the rows under it "
                         f"have {count}, as --columns names (the partial line a capture starts with?); {SKIP_HINT}")
    rec = read_table_lines(["" if k in text or k in cut else line for k, line in enumerate(lines)], str(path),
                           columns, units, bad_lines)
    if text:
        rec.metadata["preamble"] = listing([f"line {k + 1}: {lines[k].strip()}" for k in text])
    if cut:
        mine = [f"{k + 1} ({len(_cells(lines[k], delimiter))} fields, --columns names {count})" for k in cut]
        known = rec.metadata.get("skipped_lines")
        rec.metadata["skipped_lines"] = f"{known}; {'; '.join(mine)}" if known else listing(mine, len(rec) + len(cut))
    return rec


def _title_lines(lines, start: int, delimiter) -> int:
    """How many lines of free text (a title, a start-up banner) come before a header that names the columns of
    the data under it: 0 when the first line already has as many fields as the data. The header is the first
    line of as many fields, all names, with a row of mostly numbers after it (or after a row of units under
    the names: `s,uT,uT,uT`)."""
    def cells(line):  # quotes aside ("Bx","nT"): a quoted head is read as the unquoted one
        return [c.strip('"').strip() for c in _cells(line, delimiter)]

    def number(x):
        return _numberish(x, delimiter)

    body = [k for k in range(start, min(len(lines), start + 200)) if lines[k].strip() and not is_comment(lines[k])]
    if len(body) < 4:
        return 0
    width = Counter(len(cells(lines[k])) for k in body[len(body) // 2:]).most_common(1)[0][0]
    if width < 2:
        return 0
    for k, here in enumerate(body[:min(30, len(body) - 1)]):
        c, d = cells(lines[here]), cells(lines[body[k + 1]])
        if len(d) == width and is_units_row(d) and k + 2 < len(body):  # a units row: the data after
            d = cells(lines[body[k + 2]])
            if is_processing_row(d) and k + 3 < len(body):  # (TOA5: after its processing row)
                d = cells(lines[body[k + 3]])
        # a banner line of as many fields, all words ("Sensor: QMC5883L, range 8G, ODR 50 Hz"), is not the
        # header unless numbers follow it: look on
        if len(c) == width and all(x and not number(x) for x in c) and len(d) == width \
                and 2 * sum(number(x) for x in d) >= width:
            return here - start
    return 0


def _commented_header(lines, start: int, delimiter, count: int):
    """(line number, names, cells) when the comment line just above a header-less table names its columns
    (`# t mx my mz`, `# time [s], Bx [nT], ...`: one name per column, none a number, a magnetometer among
    them), else None."""
    from .columns import find_magnetometer
    from .csv import _split_header

    if start == 0 or not is_comment(lines[start - 1]):
        return None
    body = comment_text(lines[start - 1])
    cells = body.split(delimiter) if delimiter and delimiter in body else body.split()
    pairs = [_split_header(c) for c in cells]
    names = [n for n, _ in pairs]
    if len(names) != count or any(not n or _is_number(n) for n in names) or len(set(names)) != len(names):
        return None
    try:
        if find_magnetometer(names) is None:
            return None
    except ValueError:  # two magnetometer triples: the names are still the columns' (the user picks one)
        pass
    return start, names, cells


def _delimiter(lines, start: int):
    """The delimiter of the table: tab, comma or semicolon — the one found in most of the header and the
    first 20 data lines (so one garbled first line does not decide; ';' over ',' when both are) — else
    whitespace (None)."""
    sample = [lines[start]] + data_lines(lines, start + 1, 20)
    counts = {c: sum(c in line for line in sample) for c in ("\t", ",", ";")}
    best = max(counts, key=lambda c: counts[c])
    if best == "," and counts[";"] > len(sample) / 2 and _decimal_comma_columns(data_cells(sample[1:], ";")):
        best = ";"  # both in most lines, and the ';' cells are decimal-comma numbers (1,25;0,5)
    return best if counts[best] > len(sample) / 2 else None


def write_recording(path, rec: Recording) -> Path:
    """Write `rec` in the format of the path's extension (.csv .npz .mat .parquet/.pq .json)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if not rec.columns:  # .npz, .mat and Parquet wrote it, and it read back as an empty recording
        raise ValueError(f"{path}: no columns to write")
    if suffix == ".csv":
        return write_csv(path, rec)
    if suffix == ".npz":
        from .npz import write_npz

        return write_npz(path, rec)
    if suffix == ".mat":
        from .matlab import write_mat

        return write_mat(path, rec)
    if suffix in (".parquet", ".pq"):
        from .parquet import write_parquet

        return write_parquet(path, rec)
    if suffix == ".json":
        from .real import write_json_recording

        return write_json_recording(path, rec)
    raise ValueError(f"{path}: unknown recording extension {suffix or '(none)'!r}; use one of {', '.join(WRITERS)}")
