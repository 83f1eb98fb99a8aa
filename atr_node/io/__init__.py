"""Recorded mission logs (ICD section 4)."""

from .atrlog import LINKS, AtrLogReader, AtrLogWriter, LogRecord, read_atrlog

__all__ = ["LINKS", "AtrLogReader", "AtrLogWriter", "LogRecord", "read_atrlog"]
