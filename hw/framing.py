"""Line framing for byte streams, kept apart from the transport (pyserial's ``Packetizer`` model).

A serial port or socket delivers arbitrary chunks; :class:`LineFramer` turns them into lines,
whatever the split. Any run of CR and LF ends a line (CR LF, bare LF and bare CR devices all
work) and empty lines are skipped. A line that grows past ``max_line_bytes`` without a
terminator (a babbling device, binary noise) is discarded up to the next terminator and
counted in ``overflows``; it never grows the buffer without bound.
"""

from __future__ import annotations

import re

_EOL = re.compile(rb"[\r\n]+")


class LineFramer:
    """Split a byte stream into lines.

    Parameters
    ----------
    max_line_bytes
        Longest line kept, terminator excluded. Longer lines are dropped whole and counted.
        The default leaves room for malformed sentences (82 is the NMEA limit) so that the
        decoder, not the framer, counts them as too long.
    """

    def __init__(self, max_line_bytes: int = 1024) -> None:
        if max_line_bytes < 1:
            raise ValueError(f"max_line_bytes = {max_line_bytes}: expected >= 1")
        self.max_line_bytes = int(max_line_bytes)
        self._buf = bytearray()
        self._discarding = False
        self.lines = 0
        self.overflows = 0

    def feed(self, data: bytes) -> list[bytes]:
        """Take a chunk; return the lines it completes (without terminators), in order."""
        self._buf += data
        parts = _EOL.split(self._buf)
        tail = parts.pop()  # text after the last terminator: an incomplete line
        out: list[bytes] = []
        for part in parts:
            if self._discarding:  # the rest of an overlong line: its terminator ends the discard
                self._discarding = False
                continue
            if not part:
                continue
            if len(part) > self.max_line_bytes:
                self.overflows += 1
                continue
            out.append(bytes(part))
        if len(tail) > self.max_line_bytes:
            if not self._discarding:
                self.overflows += 1
            self._discarding = True
            tail = b""
        self._buf = bytearray(tail)
        self.lines += len(out)
        return out

    def flush(self) -> list[bytes]:
        """The pending incomplete line, if any (end of stream); the framer is then empty."""
        tail, self._buf = bytes(self._buf), bytearray()
        if self._discarding or not tail:
            self._discarding = False
            return []
        self.lines += 1
        return [tail]

    @property
    def pending(self) -> int:
        """Bytes held for an incomplete line."""
        return len(self._buf)
