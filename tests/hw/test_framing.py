"""Line framing: the same lines whatever the chunking; overlong lines dropped and counted."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from hw.framing import LineFramer

LINE = st.binary(min_size=1, max_size=40).map(lambda b: b.replace(b"\r", b"x").replace(b"\n", b"y"))


@settings(max_examples=200, deadline=None)
@given(lines=st.lists(LINE, max_size=20), eols=st.data(), cuts=st.lists(st.integers(0, 2000), max_size=30))
def test_lines_independent_of_chunking_and_terminator(lines, eols, cuts):
    stream = b"".join(l + eols.draw(st.sampled_from([b"\r\n", b"\n", b"\r", b"\r\n\r\n"])) for l in lines)
    framer = LineFramer(64)
    got: list[bytes] = []
    bounds = sorted({0, len(stream), *[c % (len(stream) + 1) for c in cuts]})
    for a, b in zip(bounds, bounds[1:]):
        got += framer.feed(stream[a:b])
    got += framer.flush()
    assert got == lines
    assert framer.overflows == 0 and framer.pending == 0


def test_overlong_line_is_dropped_whole_and_the_next_kept():
    framer = LineFramer(10)
    out = framer.feed(b"ok\r\n" + b"z" * 25)
    out += framer.feed(b"z" * 25)  # still the same overlong line, spread over chunks
    out += framer.feed(b"zz\r\nnext\r\n")
    assert out == [b"ok", b"next"]
    assert framer.overflows == 1 and framer.pending == 0


def test_incomplete_tail_waits_for_its_terminator():
    framer = LineFramer()
    assert framer.feed(b"$GPHDT,1") == [] and framer.pending == 8
    assert framer.feed(b",T*00\n") == [b"$GPHDT,1,T*00"]
