"""Calibration from measured records: the record reader (CSV time series, SI on reading)."""

from .record import METADATA_KEYS, OUTPUTS, QUANTITIES, Record, read_record

__all__ = ["METADATA_KEYS", "OUTPUTS", "QUANTITIES", "Record", "read_record"]
