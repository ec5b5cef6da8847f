"""Reading fluxcal's own saved JSON files (calibrations, ring calibrations, drift models, filters): one
wording for every way such a file can be wrong, naming the file and what it should have been."""
from __future__ import annotations

import json

from .io.csv import readable_file


def load_json_object(path, what: str) -> dict:
    """The JSON object saved in `path`, or ValueError naming `path`, `what` it should be ("a fluxcal
    calibration") and the problem: a folder or a pipe (which would block), an unreadable file, bytes that
    are not UTF-8 text, invalid JSON (line and column), or a document that is not an object."""
    path = readable_file(path, what, remedy="")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    try:
        data = json.loads(raw.decode("utf-8-sig"))  # (a byte-order mark, as a Windows editor saves one, is no error)
    except UnicodeDecodeError as exc:  # a binary or mis-encoded file: name the byte, not the codec
        raise ValueError(f"{path}: not {what} (byte 0x{exc.object[exc.start]:02x} at offset {exc.start} is not "
                         "text)") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not {what} (not valid JSON at line {exc.lineno}, column {exc.colno}: "
                         f"{exc.msg}; a truncated file?)") from None
    except RecursionError:
        raise ValueError(f"{path}: not {what} (JSON nested too deeply)") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not {what} (a JSON {type(data).__name__}, expected an object)")
    return data
