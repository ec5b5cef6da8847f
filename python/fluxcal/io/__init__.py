"""Recordings and their files. A Recording is named columns plus units and metadata."""
from .recording import Recording
from .csv import read_csv, write_csv

__all__ = ["Recording", "read_csv", "write_csv"]
