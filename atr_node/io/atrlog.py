"""The recorded mission log ``.atrlog`` (ICD section 4).

A file of consecutive msgpack maps, in arrival order::

    {"t": float (arrival, UNIX seconds), "link": "sonar" | "nmea" | "can", "msg": ...}

    link "sonar": msg = tile map (ICD section 1)
    link "nmea":  msg = bin, one sentence with or without CR LF
    link "can":   msg = {"id": int, "data": bin, "ext": bool}

The reader streams: it holds one read buffer, never the file. A truncated last record (power
cut while recording) is dropped with a warning and everything before it is kept. A record
that decodes but breaks the table above is skipped with a warning naming its byte offset
(or raised, with ``strict=True``); the tile map inside a sonar record is validated later by
the tile parser, not here.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Iterator

import msgpack

from ..errors import LogFormatError

log = logging.getLogger(__name__)

LINKS = ("sonar", "nmea", "can")
READ_SIZE = 1 << 20
MAX_BUFFER = 1 << 30  # a record may hold a large tile


@dataclass(frozen=True)
class LogRecord:
    """One record of an .atrlog, with the byte offset where it starts."""

    t: float
    link: str
    msg: Any
    offset: int = 0


def check_record(obj: Any) -> str | None:
    """Why ``obj`` is not a valid record of ICD section 4, or None when it is."""
    if not isinstance(obj, dict):
        return f"expected a map, got {type(obj).__name__}"
    for k in ("t", "link", "msg"):
        if k not in obj:
            return f"missing key '{k}'"
    t = obj["t"]
    if isinstance(t, bool) or not isinstance(t, (int, float)) or t != t or t in (float("inf"), float("-inf")):
        return f"'t' must be a finite number, got {t!r}"
    link, msg = obj["link"], obj["msg"]
    if link not in LINKS:
        return f"'link' must be one of {list(LINKS)}, got {link!r}"
    if link == "sonar" and not isinstance(msg, dict):
        return f"a sonar record's msg must be a tile map, got {type(msg).__name__}"
    if link == "nmea" and not isinstance(msg, (bytes, bytearray)):
        return f"an nmea record's msg must be bin, got {type(msg).__name__}"
    if link == "can":
        if not isinstance(msg, dict):
            return f"a can record's msg must be a map, got {type(msg).__name__}"
        cid, data, ext = msg.get("id"), msg.get("data"), msg.get("ext")
        if isinstance(cid, bool) or not isinstance(cid, int) or cid < 0:
            return f"a can record's id must be an integer >= 0, got {cid!r}"
        if not isinstance(data, (bytes, bytearray)):
            return f"a can record's data must be bin, got {type(data).__name__}"
        if not isinstance(ext, bool):
            return f"a can record's ext must be true or false, got {ext!r}"
    return None


def _can_ok(msg: Any) -> bool:
    """True for a can msg of exact types (int id >= 0, bin data, bool ext); False sends the
    record to :func:`check_record`, which accepts a superset and words the rejection."""
    if type(msg) is not dict:
        return False
    cid = msg.get("id")
    return type(cid) is int and cid >= 0 and type(msg.get("data")) is bytes and type(msg.get("ext")) is bool


_new_object = object.__new__


def _record(t: float, link: str, msg: Any, offset: int) -> LogRecord:
    """``LogRecord(t, link, msg, offset)`` without the frozen dataclass's per-field
    ``object.__setattr__`` (the same object in every respect, about 2x cheaper)."""
    rec = _new_object(LogRecord)
    d = rec.__dict__
    d["t"] = t
    d["link"] = link
    d["msg"] = msg
    d["offset"] = offset
    return rec


@dataclass
class AtrLogReader:
    """Stream the records of an .atrlog.

    Iterating yields :class:`LogRecord` in file order. Counters tell what happened:
    ``records`` (yielded), ``rejected`` (decoded but malformed, skipped), ``truncated``
    (True when the file ended inside a record).
    """

    path: str | os.PathLike[str]
    strict: bool = False
    records: int = 0
    rejected: int = 0
    truncated: bool = False
    errors: list[str] = field(default_factory=list)

    def __iter__(self) -> Iterator[LogRecord]:
        path = str(self.path)
        with open(path, "rb") as fh:
            yield from self._iter_stream(fh, path)

    def _iter_stream(self, fh: BinaryIO, path: str) -> Iterator[LogRecord]:
        unpacker = msgpack.Unpacker(fh, raw=False, read_size=READ_SIZE, max_buffer_size=MAX_BUFFER,
                                    strict_map_key=False)
        size = os.fstat(fh.fileno()).st_size if hasattr(fh, "fileno") else None
        offset = 0
        unpack, tell = unpacker.unpack, unpacker.tell
        while True:
            try:
                obj = unpack()
            except msgpack.OutOfData:
                end = offset  # end of the last complete record (tell() may be past it here)
                if size is not None and end < size:
                    self.truncated = True
                    msg = f"{path}: truncated last record at byte {end} ({size - end} bytes ignored)"
                    log.warning(msg)
                    self.errors.append(msg)
                return
            except (msgpack.ExtraData, msgpack.FormatError, msgpack.StackError, ValueError, TypeError) as exc:
                # TypeError: a map whose key is a map or array (unhashable)
                # Not msgpack from here on: nothing after it can be framed reliably.
                msg = f"{path}: undecodable data at byte {offset}: {exc}; the rest of the file is ignored"
                if self.strict:
                    raise LogFormatError(f"undecodable data: {exc}", path=path, offset=offset) from None
                log.warning(msg)
                self.errors.append(msg)
                self.rejected += 1
                return
            start, offset = offset, tell()
            # Fast path for the usual records, by exact types (a float t, an nmea bin, a can map
            # of int, bin and bool, a sonar map); anything else goes to check_record, which
            # accepts a superset of these and words the rejection. t - t is nan for inf and nan.
            if type(obj) is dict:
                t, link, rmsg = obj.get("t"), obj.get("link"), obj.get("msg")
                if type(t) is float and t - t == 0.0 and (
                        (link == "nmea" and type(rmsg) is bytes) or (link == "can" and _can_ok(rmsg))
                        or (link == "sonar" and type(rmsg) is dict)):
                    self.records += 1
                    yield _record(t, link, rmsg, start)  # t is a float: float(t) would return it
                    continue
            why = check_record(obj)
            if why is not None:
                if self.strict:
                    raise LogFormatError(why, path=path, offset=start)
                self.rejected += 1
                msg = f"{path}: record at byte {start} rejected: {why}"
                log.warning(msg)
                self.errors.append(msg)
                continue
            self.records += 1
            yield LogRecord(t=float(obj["t"]), link=obj["link"], msg=obj["msg"], offset=start)


def read_atrlog(path: str | os.PathLike[str], *, strict: bool = False) -> Iterator[LogRecord]:
    """Stream the records of an .atrlog (see :class:`AtrLogReader`)."""
    return iter(AtrLogReader(path, strict=strict))


class AtrLogWriter:
    """Append records to an .atrlog.

    ``flush_every`` records, the file is flushed to the OS (and ``fsync``-ed with
    ``fsync=True``), so a power cut loses at most that many records and leaves a file whose
    truncated tail the reader skips.
    """

    def __init__(self, path: str | os.PathLike[str], *, append: bool = False, flush_every: int = 1,
                 fsync: bool = False) -> None:
        self.path = Path(path)
        self._fh = open(self.path, "ab" if append else "wb")
        self._packer = msgpack.Packer(use_bin_type=True)
        self.flush_every = max(int(flush_every), 1)
        self.fsync = fsync
        self.records = 0
        self.bytes = self._fh.tell()
        self._flushed = self.bytes

    def write(self, t: float, link: str, msg: Any) -> int:
        """Append one record; return its byte offset. The record is checked first."""
        rec = {"t": float(t), "link": link, "msg": msg}
        why = check_record(rec)
        if why is not None:
            raise LogFormatError(why, path=str(self.path), offset=self.bytes)
        data = self._packer.pack(rec)
        offset = self.bytes
        try:
            self._fh.write(data)
        except OSError:
            self._rewind()
            raise
        self.bytes += len(data)
        self.records += 1
        if self.records % self.flush_every == 0:
            self.flush()
        return offset

    def write_record(self, rec: LogRecord) -> int:
        return self.write(rec.t, rec.link, rec.msg)

    def flush(self) -> None:
        """Flush to the OS. On an error (disk full), the file is cut back to the end of the last
        flushed record and the error raised: the records since are not in the file, and the
        file stays a sequence of whole records that later writes can extend."""
        try:
            self._fh.flush()
            if self.fsync:
                os.fsync(self._fh.fileno())
        except OSError:
            self._rewind()
            raise
        self._flushed = self.bytes

    def _rewind(self) -> None:
        try:
            self._fh.close()  # drops what is still buffered (its flush fails again)
        except OSError:
            pass
        try:
            os.truncate(self.path, self._flushed)  # a partial record must not stay in the middle
        except OSError:
            pass
        self._fh = open(self.path, "ab")
        self.bytes = self._flushed

    def close(self) -> None:
        if not self._fh.closed:
            self.flush()
            self._fh.close()

    def __enter__(self) -> "AtrLogWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
