"""The recorded mission log ``.atrlog`` (ICD section 4).

A file of consecutive msgpack maps, in arrival order::

    {"t": float (arrival, UNIX seconds), "link": "sonar" | "nmea" | "can", "msg": ...}

    link "sonar": msg = tile map (ICD section 1)
    link "nmea":  msg = bin, one sentence with or without CR LF
    link "can":   msg = {"id": int, "data": bin, "ext": bool}

The reader streams: it holds one read buffer, never the file. A truncated last record (power
cut while recording) is dropped with a warning and everything before it is kept. A record
that breaks the table above, or whose frame is whole but whose content cannot be decoded
(bad UTF-8, an unhashable key), costs only itself; bytes that are not records at all are
skipped up to the next valid record. Both are counted by reason, the first of each kind
warned with its byte offset (or raised, with ``strict=True``); see :class:`AtrLogReader`.
The tile map inside a sonar record is validated later by the tile parser, not here.
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Iterator

import msgpack

from ..errors import LogFormatError

log = logging.getLogger(__name__)

LINKS = ("sonar", "nmea", "can")
READ_SIZE = 1 << 20
MAX_RECORD_BYTES = 1 << 27
"""Largest record :class:`AtrLogReader` decodes by default (128 MiB: a tile of 2^23 float64
pixels, the node's ``node.max_tile_pixels``, takes 64 MiB). A longer record (a 1 GB NMEA line)
is skipped by its frame's length, read from its headers, without being loaded: memory stays
bounded whatever the file holds."""
MAX_ERRORS = 100  # messages kept in AtrLogReader.errors; the rest are only counted
SCAN_SIZE = 1 << 20  # bytes searched at a time for the next record after garbage
RESYNC_WINDOW_S = 86400.0  # a record found after garbage this far from the last good t needs a second
RECORD_KEYS = ("t", "link", "msg")
# How a record frame starts: a map header (fixmap of 1-15 entries, map16) and the key "t",
# "link" or "msg" as a fixstr. _HEAD_MAX: the longest match.
_RECORD_HEAD = re.compile(rb"(?:[\x81-\x8f]|\xde[\x00-\xff]{2})(?:\xa1t|\xa4link|\xa3msg)")
# Where reading may resume after garbage: a map header, then "t" and the header of a number
# (fixint, int, float) or "link" and a str of 3 to 5 bytes, so that runs of look-alike bytes
# (b"\x81\xa1t" repeated) cost one regex match each, not a decode.
# A lookahead (zero width), so candidates may overlap: a rejected candidate whose map16 header
# swallows the next bytes must not hide a record head starting inside it (found by Hypothesis:
# b"\x00\xde\x00" before a record's b"\x83\xa1t").
_RESYNC_HEAD = re.compile(rb"(?=(?:[\x81-\x8f]|\xde[\x00-\xff]{2})(?:\xa1t[\x00-\x7f\xca-\xd3\xe0-\xff]|\xa4link[\xa3-\xa5]))")
_HEAD_MAX = 9
UNDECODABLE_STR = "undecodable str"
UNHASHABLE_KEY = "unhashable key"
GARBAGE = "garbage skipped"
TOO_LONG = "record too long"
CHECK_REASONS = ("missing key", "bad t", "bad link", "bad msg")  # of check_record, by _reason


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

    Iterating yields :class:`LogRecord` in file order. Damage costs only itself:

    * a record whose frame is whole but whose content cannot be decoded (bad UTF-8 in a str,
      a map or array as a map key) or breaks ICD section 4 (``t``, ``link``, ``msg``) is
      skipped, and reading goes on at the next frame;
    * bytes that are not records at all (a bad byte, a block of zeros, a record overwritten)
      are skipped up to the next position where a whole, valid record decodes (see
      :meth:`_resync`), and reading goes on there;
    * a truncated last record (power cut while recording) is dropped.

    Each kind is warned once with its byte offset, then counted (``reasons``), and the counts
    are summed up in one line at the end (:meth:`summary_text`). A file that holds no valid
    record at all (empty, or not an .atrlog) raises :class:`LogFormatError` in one line,
    unless ``allow_empty`` (the live node's own, possibly just-created, recording).

    Attributes
    ----------
    records
        Records yielded.
    rejected
        Records rejected plus blocks of garbage skipped (one per block).
    reasons
        ``rejected`` by reason: ``undecodable str``, ``unhashable key``, ``bad t``,
        ``bad link``, ``bad msg``, ``missing key``, ``record too long``, ``garbage skipped``.
    skipped_bytes
        Bytes inside the skipped garbage blocks.
    truncated
        True when the file ended inside a record.
    errors
        The first :data:`MAX_ERRORS` messages, each naming the file and the byte offset.
    """

    path: str | os.PathLike[str]
    strict: bool = False
    allow_empty: bool = False
    records: int = 0
    rejected: int = 0
    truncated: bool = False
    skipped_bytes: int = 0
    errors: list[str] = field(default_factory=list)
    reasons: Counter = field(default_factory=Counter)
    max_record_bytes: int = MAX_RECORD_BYTES
    """A record longer than this is rejected (``record too long``) without being loaded."""

    def __iter__(self) -> Iterator[LogRecord]:
        path = str(self.path)
        try:
            fh = open(path, "rb")
        except OSError as exc:
            raise LogFormatError(f"cannot open: {exc.strerror or exc}", path=path) from None
        with fh:
            yield from self._iter_stream(fh, path)

    def summary_text(self) -> str:
        """``3 records rejected: garbage skipped x 1 (412 bytes), undecodable str x 2``
        (empty when nothing was rejected)."""
        if not self.rejected:
            return ""
        parts = [f"{k} x {v}" + (f" ({self.skipped_bytes} bytes)" if k == GARBAGE else "")
                 for k, v in sorted(self.reasons.items())]
        return f"{self.rejected} record{'s' if self.rejected != 1 else ''} rejected: " + ", ".join(parts)

    def report(self) -> dict[str, Any]:
        """The counters as a dict (for a run summary)."""
        return {"records": self.records, "rejected": self.rejected, "reasons": dict(self.reasons),
                "skipped_bytes": self.skipped_bytes, "truncated": self.truncated}

    def _iter_stream(self, fh: BinaryIO, path: str) -> Iterator[LogRecord]:
        size = os.fstat(fh.fileno()).st_size
        if size == 0:
            self._no_record(path, "empty file")
            return
        pos = 0  # where the current unpacker starts; a fresh one after every irregular frame
        last_t: float | None = None
        while pos < size:
            fh.seek(pos)
            unpacker = msgpack.Unpacker(fh, raw=False, read_size=min(READ_SIZE, self.max_record_bytes),
                                        max_buffer_size=self.max_record_bytes, strict_map_key=False)
            unpack, tell = unpacker.unpack, unpacker.tell
            offset = pos
            kind, why, frame_end = None, "", 0
            while True:
                try:
                    obj = unpack()
                except msgpack.OutOfData:
                    kind, why = "out of data", "a frame longer than the rest of the file"
                    break
                except msgpack.BufferFull:
                    kind, why = TOO_LONG, f"longer than the reader's limit of {self.max_record_bytes} bytes"
                    break
                except UnicodeDecodeError as exc:
                    kind, why = UNDECODABLE_STR, str(exc)
                    break
                except TypeError as exc:  # a map or array as a map key: unhashable
                    kind, why = UNHASHABLE_KEY, str(exc)
                    break
                except (msgpack.UnpackException, ValueError) as exc:  # FormatError, StackError, lengths
                    kind, why = GARBAGE, str(exc) or type(exc).__name__
                    break
                start, offset = offset, pos + tell()
                # Fast path for the usual records, by exact types (a float t, an nmea bin, a can map
                # of int, bin and bool, a sonar map); anything else goes to check_record, which
                # accepts a superset of these and words the rejection. t - t is nan for inf and nan.
                if type(obj) is dict:
                    t, link, rmsg = obj.get("t"), obj.get("link"), obj.get("msg")
                    if type(t) is float and t - t == 0.0 and (
                            (link == "nmea" and type(rmsg) is bytes) or (link == "can" and _can_ok(rmsg))
                            or (link == "sonar" and type(rmsg) is dict)):
                        self.records += 1
                        last_t = t
                        yield _record(t, link, rmsg, start)  # t is a float: float(t) would return it
                        continue
                why = check_record(obj)
                if why is None:
                    self.records += 1
                    last_t = float(obj["t"])
                    yield LogRecord(t=last_t, link=obj["link"], msg=obj["msg"], offset=start)
                    continue
                if isinstance(obj, dict) and next(iter(obj), None) in RECORD_KEYS:
                    # framed as a record ({"t": ..., ...}): it costs only itself (checked below)
                    kind, frame_end, offset = _reason(why), offset, start
                    break
                offset = start  # not a record at all (an int from a zero byte...): garbage
                kind = GARBAGE
                break
            start = offset
            if start >= size:
                break
            end, text = None, ""
            if kind in (TOO_LONG, UNDECODABLE_STR, UNHASHABLE_KEY):  # skipped by its headers, not decoded
                end = _record_frame_end(fh, start, size)
                text = f"record at byte {start} rejected: {kind}: {why} ({(end or start) - start} bytes skipped)"
            elif kind in CHECK_REASONS:
                end, text = frame_end, f"record at byte {start} rejected: {why}"
            # a whole record frame with bad content, and a record (or the end) right after it: skip
            # exactly it; otherwise its length may be damaged too and hide records: resync instead
            if end is not None and (end >= size or _RECORD_HEAD.match(_peek(fh, end))):
                self._reject(path, kind, start, text)
                pos = end
                continue
            nxt = self._resync(fh, start + 1, size, last_t)
            if nxt is None:
                if kind == "out of data" and _RECORD_HEAD.match(_peek(fh, start)):
                    self.truncated = True
                    msg = f"{path}: truncated last record at byte {start} ({size - start} bytes ignored)"
                    log.warning(msg)
                    self._error(msg)
                    break
                nxt = size
            if nxt == size and self.records == 0 and not self.allow_empty:
                self._no_record(path, f"no valid record in {size} bytes (not an .atrlog recording?)")
                return
            self.skipped_bytes += nxt - start
            self._reject(path, GARBAGE, start, f"bytes {start}-{nxt} rejected: {why or 'not msgpack'}; "
                         f"{nxt - start} bytes skipped " + ("to the next record" if nxt < size else "to the end"))
            pos = nxt
        if self.records == 0 and not self.allow_empty:
            self._no_record(path, f"no valid record in {size} bytes" + (
                f" ({self.summary_text()})" if self.rejected else " (only a truncated record)"))
            return
        if self.rejected:
            log.warning("%s: %s", path, self.summary_text())

    def _resync(self, fh: BinaryIO, begin: int, size: int, last_t: float | None) -> int | None:
        """The first offset >= ``begin`` where a valid record decodes, or None.

        Candidates are the byte patterns a record starts with: a map header followed by the key
        "t", "link" or "msg" (rare in other data: about one per megabyte of random pixels).
        A candidate is taken only when its whole frame decodes to a valid record whose ``t``
        is within :data:`RESYNC_WINDOW_S` of the last good record (or the record after it is
        valid too), so garbage that happens to start like a record is not mistaken for one.
        The work is one regex pass over the bytes plus one decode per candidate."""
        p = begin
        while p < size:
            fh.seek(p)
            chunk = fh.read(SCAN_SIZE + _HEAD_MAX)
            for m in _RESYNC_HEAD.finditer(chunk):
                if m.start() >= SCAN_SIZE:
                    break
                q = p + m.start()
                if _acceptable(fh, q, size, last_t, self.max_record_bytes):
                    return q
            p += SCAN_SIZE
        return None

    def _reject(self, path: str, reason: str, offset: int, text: str) -> None:
        if self.strict:
            raise LogFormatError(text, path=path, offset=offset)
        self.rejected += 1
        self.reasons[reason] += 1
        msg = f"{path}: {text}"
        self._error(msg)
        if self.reasons[reason] == 1:  # the first of each kind in full; the rest are counted
            log.warning("%s (further ones are counted, not listed)", msg)
        else:
            log.debug("%s", msg)

    def _error(self, msg: str) -> None:
        if len(self.errors) < MAX_ERRORS:
            self.errors.append(msg)

    def _no_record(self, path: str, text: str) -> None:
        if not self.allow_empty:
            raise LogFormatError(text, path=path)
        log.warning("%s: %s", path, text)


def _reason(why: str) -> str:
    """The counted reason of a :func:`check_record` message."""
    if why.startswith("missing key"):
        return "missing key"
    if why.startswith("'t'"):
        return "bad t"
    if why.startswith("'link'"):
        return "bad link"
    return "bad msg"


def _peek(fh: BinaryIO, offset: int) -> bytes:
    fh.seek(offset)
    return fh.read(_HEAD_MAX)


def _decode_at(fh: BinaryIO, offset: int, limit: int = MAX_RECORD_BYTES) -> tuple[Any, int] | None:
    """(object, end offset) of the msgpack frame at ``offset``, or None when it does not decode
    within ``limit`` bytes."""
    fh.seek(offset)
    u = msgpack.Unpacker(fh, raw=False, read_size=1 << 16, max_buffer_size=limit, strict_map_key=False)
    try:
        obj = u.unpack()
    except (msgpack.UnpackException, ValueError, TypeError):
        return None
    return obj, offset + u.tell()


def _record_frame_end(fh: BinaryIO, offset: int, size: int) -> int | None:
    """End of the frame at ``offset`` when it is framed as a record (a map whose first key is
    "t", "link" or "msg") and whole; None otherwise. The frame is stepped over from its headers
    (:func:`_walk_frame_end`), not built, so bad UTF-8 or an unhashable key inside it do not
    matter, and its size costs no memory."""
    if not _RECORD_HEAD.match(_peek(fh, offset)):
        return None
    return _walk_frame_end(fh, offset, size)


_FIXED = {0xc0: 0, 0xc2: 0, 0xc3: 0, 0xca: 4, 0xcb: 8, 0xcc: 1, 0xcd: 2, 0xce: 4, 0xcf: 8, 0xd0: 1, 0xd1: 2,
          0xd2: 4, 0xd3: 8, 0xd4: 2, 0xd5: 3, 0xd6: 5, 0xd7: 9, 0xd8: 17}
"""msgpack first bytes followed by a fixed number of bytes (fixext: type byte included)."""
_SIZED = {0xc4: (1, 0), 0xc5: (2, 0), 0xc6: (4, 0), 0xc7: (1, 1), 0xc8: (2, 1), 0xc9: (4, 1), 0xd9: (1, 0),
          0xda: (2, 0), 0xdb: (4, 0)}
"""bin, ext and str: (bytes of the length, extra bytes after it: the ext type)."""
_WALK_MAX_OBJECTS = 1 << 20


def _walk_frame_end(fh: BinaryIO, offset: int, size: int) -> int | None:
    """End of the msgpack frame at ``offset`` from its headers only (str, bin and ext payloads
    are stepped over, never read), or None when the frame is not whole, not msgpack, or holds
    more than a million objects: the skip of a record too long to load."""
    pos, pending, seen = offset, 1, 0
    while pending:
        if pos >= size or seen >= _WALK_MAX_OBJECTS:
            return None
        fh.seek(pos)
        head = fh.read(5)
        b = head[0]
        pending -= 1
        seen += 1
        if b <= 0x7f or b >= 0xe0:
            pos += 1
        elif b <= 0x8f:
            pending += 2 * (b & 0x0f)
            pos += 1
        elif b <= 0x9f:
            pending += b & 0x0f
            pos += 1
        elif b <= 0xbf:
            pos += 1 + (b & 0x1f)
        elif b in _FIXED:
            pos += 1 + _FIXED[b]
        elif b in _SIZED:
            n, extra = _SIZED[b]
            if len(head) < 1 + n:
                return None
            pos += 1 + n + extra + int.from_bytes(head[1:1 + n], "big")
        elif b in (0xdc, 0xdd, 0xde, 0xdf):
            n = 2 if b in (0xdc, 0xde) else 4
            if len(head) < 1 + n:
                return None
            count = int.from_bytes(head[1:1 + n], "big")
            pending += count * (2 if b >= 0xde else 1)
            pos += 1 + n
        else:  # 0xc1: never used
            return None
    return pos if pos <= size else None


def _plausible_head(fh: BinaryIO, offset: int) -> bool:
    """Whether the map at ``offset`` starts with a finite number ``t`` and a known ``link``,
    read from its first few kB only. Recorders write ``t`` and ``link`` before ``msg``; checking
    them first keeps a candidate that merely looks like a record head (a few bytes inside a
    tile's pixels) from decoding the megabytes its ``msg`` may claim."""
    fh.seek(offset)
    u = msgpack.Unpacker(fh, raw=False, read_size=1 << 12, max_buffer_size=1 << 16, strict_map_key=False)
    try:
        n = u.read_map_header()
        seen: dict[Any, Any] = {}
        for _ in range(min(n, 2)):
            key = u.unpack()
            if key not in ("t", "link"):
                return False
            seen[key] = u.unpack()
    except (msgpack.UnpackException, ValueError, TypeError):
        return False
    t = seen.get("t")
    return (seen.get("link") in LINKS and isinstance(t, (int, float)) and not isinstance(t, bool)
            and math.isfinite(t))


def _acceptable(fh: BinaryIO, offset: int, size: int, last_t: float | None,
                limit: int = MAX_RECORD_BYTES) -> bool:
    """Whether reading may resume at ``offset`` (see :meth:`AtrLogReader._resync`)."""
    if not _plausible_head(fh, offset):
        return False
    got = _decode_at(fh, offset, limit)
    if got is None or check_record(got[0]) is not None:
        return False
    obj, end = got
    if last_t is None or abs(float(obj["t"]) - last_t) <= RESYNC_WINDOW_S or end >= size:
        return True
    after = _decode_at(fh, end, limit)  # far in time: believe it only when the next record is valid too
    return after is not None and check_record(after[0]) is None


def read_atrlog(path: str | os.PathLike[str], *, strict: bool = False,
                allow_empty: bool = False) -> Iterator[LogRecord]:
    """Stream the records of an .atrlog (see :class:`AtrLogReader`)."""
    return iter(AtrLogReader(path, strict=strict, allow_empty=allow_empty))


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
