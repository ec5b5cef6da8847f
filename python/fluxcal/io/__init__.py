"""Recordings and their files. A Recording is named columns plus units and metadata.

read_recording / write_recording handle every format (CSV and other text tables, .npz, .mat, Parquet,
JSON), chosen by content when reading and by extension when writing; see fluxcal.io.formats."""
from .recording import Recording
from .csv import read_csv, write_csv
from .formats import read_recording, sniff, write_recording
from .matlab import read_mat, write_mat
from .npz import read_npz, write_npz
from .parquet import read_parquet, write_parquet
from .real import read_json_recording, write_json_recording

__all__ = ["Recording", "read_csv", "read_json_recording", "read_mat", "read_npz", "read_parquet",
           "read_recording", "sniff", "write_csv", "write_json_recording", "write_mat", "write_npz",
           "write_parquet", "write_recording"]
