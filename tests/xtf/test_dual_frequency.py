"""XTF from dual-frequency sonars (two side-scan channels per side, e.g. 100 and 500 kHz): which
channel is read (``--frequency`` / ``recording.frequency``), what is said about the others.

The files are made the way such recorders lay them out: one ping packet with four channels,
``ChanInfo`` 0-3 saying side and frequency. They are built from two files our XTF writer makes
(one per frequency, the same pings), merged packet by packet here, so every channel header and
its samples are the writer's; only the channel numbers and the file header's channel table
are set by the merge.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pyxtf.xtf_ctypes import XTFFileHeader, XTFPingChanHeader, XTFPingHeader

from atr_node.batch.grids import check_positions
from atr_node.config import settings_from_dict
from atr_node.errors import ConfigError, LogFormatError
from atr_node.io.atrlog import LogRecord, read_atrlog
from atr_node.io.xtf import XtfReader
from atr_node.io.xtf_packets import pick_channel
from atr_node.io.xtf_write import write_xtf
from atr_node.records.tile import Tile

from .conftest import make_tile, run_cli

ROWS, COLS = 6, 20


def _pair(freq_hz: float, seed: int) -> list[Tile]:
    """Port and starboard tiles of the same pings at one frequency (pixels differ by seed)."""
    out = []
    for side in ("port", "stbd"):
        t = make_tile(side, rows=ROWS, cols=COLS, rng=np.random.default_rng([seed, side == "port"]))
        out.append(dataclasses.replace(t, sensor=dataclasses.replace(t.sensor, frequency_hz=freq_hz)))
    return out


def _packets(path) -> tuple[XTFFileHeader, list[tuple[XTFPingHeader, list[tuple[XTFPingChanHeader, bytes]]]]]:
    """The file header and each ping's channels (header, sample bytes) of a file our writer made."""
    raw = path.read_bytes()
    header = XTFFileHeader.from_buffer_copy(raw[:1024])
    at, pings = 1024, []
    hs, cs = 256, 64  # ping header, channel header (bytes)
    while at < len(raw):
        ping = XTFPingHeader.from_buffer_copy(raw[at:at + hs])
        end, pos, chans = at + ping.NumBytesThisRecord, at + hs, []
        for _ in range(ping.NumChansToFollow):
            ch = XTFPingChanHeader.from_buffer_copy(raw[pos:pos + cs])
            n = ch.NumSamples * header.ChanInfo[ch.ChannelNumber].BytesPerSample
            chans.append((ch, raw[pos + cs:pos + cs + n]))
            pos += cs + n
        pings.append((ping, chans))
        at = end
    return header, pings


def dual_frequency_xtf(tmp_path, *, order=(("low", "port"), ("low", "stbd"), ("high", "port"), ("high", "stbd")),
                       low_hz: float = 100e3, high_hz: float = 500e3, known: bool = True):
    """A four-channel XTF (``order``: the channels as they follow in each ping) and the tiles
    written at each frequency; ``known=False`` zeroes every frequency field (older recorders)."""
    tiles = {"low": _pair(low_hz, 1), "high": _pair(high_hz, 2)}
    parts = {}
    for band, ts in tiles.items():
        f = tmp_path / f"{band}.xtf"
        write_xtf(f, [LogRecord(t.ping_time[-1], "sonar", t.to_map()) for t in ts])
        parts[band] = _packets(f)
    header = XTFFileHeader.from_buffer_copy(bytes(parts["low"][0]))
    header.NumberOfSonarChannels = len(order)
    side_index = {"port": 0, "stbd": 1}
    for i, (band, side) in enumerate(order):
        ci = type(header.ChanInfo[0]).from_buffer_copy(bytes(parts[band][0].ChanInfo[side_index[side]]))
        if not known:
            ci.Frequency = 0
        header.ChanInfo[i] = ci
    body = [bytes(header)]
    for k, (ping, _) in enumerate(parts["low"][1]):
        chans = []
        for i, (band, side) in enumerate(order):
            ch, data = parts[band][1][k][1][side_index[side]]
            ch = XTFPingChanHeader.from_buffer_copy(bytes(ch))
            ch.ChannelNumber = i
            if not known:
                ch.Frequency = 0
            chans.append(bytes(ch) + data)
        p = XTFPingHeader.from_buffer_copy(bytes(ping))
        p.NumChansToFollow = len(order)
        p.NumBytesThisRecord = 256 + sum(len(c) for c in chans)
        body.append(bytes(p) + b"".join(chans))
    out = tmp_path / "dual.xtf"
    out.write_bytes(b"".join(body))
    return out, tiles


def _read(path, **kw):
    reader = XtfReader(path, **kw)
    tiles = {t.side: t for t in (Tile.from_map(r.msg) for r in reader if r.link == "sonar")}
    return tiles, reader.stats


def _same(got: dict[str, Tile], want: list[Tile]) -> None:
    for t in want:
        np.testing.assert_array_equal(got[t.side].pixels, t.pixels)
        assert got[t.side].sensor.frequency_hz == t.sensor.frequency_hz


def test_the_high_frequency_channels_are_read_by_default_and_the_others_said(tmp_path):
    path, tiles = dual_frequency_xtf(tmp_path)
    got, stats = _read(path)
    _same(got, tiles["high"])
    assert stats.channels_used == {500e3: 2 * ROWS} and stats.channels_unused == {100e3: 2 * ROWS}
    line = stats.frequency_line()
    assert "500 kHz (12) read, 100 kHz (12) not" in line and "--frequency" in line
    assert line in stats.summary()
    assert not stats.skipped  # the 100 kHz channels are not "channel types" skipped


@pytest.mark.parametrize("choice, band", [("low", "low"), ("LOW", "low"), ("high", "high"), (100, "low"),
                                          ("100", "low"), (455.0, "high"), ("530", "high")])
def test_the_channel_asked_for_is_read(tmp_path, choice, band):
    path, tiles = dual_frequency_xtf(tmp_path)
    got, stats = _read(path, frequency=choice)
    _same(got, tiles[band])
    assert sum(stats.channels_unused.values()) == 2 * ROWS


def test_channels_in_any_order_are_matched_by_frequency_on_each_side(tmp_path):
    order = (("high", "port"), ("low", "stbd"), ("low", "port"), ("high", "stbd"))
    path, tiles = dual_frequency_xtf(tmp_path, order=order)
    _same(_read(path)[0], tiles["high"])
    _same(_read(path, frequency="low")[0], tiles["low"])


def test_a_frequency_the_file_does_not_have_fails_at_once_naming_the_option(tmp_path):
    path, _ = dual_frequency_xtf(tmp_path)
    with pytest.raises(LogFormatError) as err:
        XtfReader(path, frequency=300)
    msg = str(err.value)
    assert "no side-scan channel at 300 kHz (--frequency)" in msg and "100, 500 kHz" in msg and str(path) in msg
    with pytest.raises(LogFormatError, match="300 kHz"):  # batch: before any task
        check_positions([path], "", 300.0)
    check_positions([path], "", 500.0)


def test_unknown_frequencies_read_the_first_channel_of_each_side(tmp_path):
    path, tiles = dual_frequency_xtf(tmp_path, known=False)
    for choice in ("high", "low", 500):  # nothing to choose by: the first, whatever was asked
        got, stats = _read(path, frequency=choice)
        np.testing.assert_array_equal(got["port"].pixels, tiles["low"][0].pixels)
        np.testing.assert_array_equal(got["stbd"].pixels, tiles["low"][1].pixels)
        assert stats.channels_unused == {0.0: 2 * ROWS}
        assert "unknown frequency (12) not" in stats.frequency_line()


def test_pick_channel_rules():
    assert pick_channel([100e3, 500e3, 500e3], "high") == 1  # the first of equals
    assert pick_channel([500e3, 100e3, 500e3], "low") == 1
    assert pick_channel([0.0, 500e3], "low") == 1  # a known frequency before an unknown one
    assert pick_channel([0.0, 0.0], "high") == 0
    assert pick_channel([100e3, 500e3], 110.0) == 0 and pick_channel([100e3, 500e3], 111.0) is None  # within 10 %
    assert pick_channel([100e3], 90.0) == 0 and pick_channel([100e3], 89.0) is None
    assert pick_channel([], "high") is None


def test_a_bad_channel_not_read_does_not_cost_the_ping(tmp_path):
    """Only the channel read is looked into: a 100 kHz channel without samples in some pings
    leaves the 500 kHz pings whole; read at 100 kHz those pings are dropped, counted."""
    path, tiles = dual_frequency_xtf(tmp_path)
    raw = bytearray(path.read_bytes())
    header, pings = _packets(path)
    # empty the low-frequency channels of ping 2: NumSamples 0, the samples cut out of the packet
    at = 1024 + sum(p.NumBytesThisRecord for p, _ in pings[:2])
    ping, chans = pings[2]
    body = b""
    for ch, data in chans:
        ch = XTFPingChanHeader.from_buffer_copy(bytes(ch))
        if header.ChanInfo[ch.ChannelNumber].Frequency < 300:
            ch.NumSamples, data = 0, b""
        body += bytes(ch) + data
    p = XTFPingHeader.from_buffer_copy(bytes(ping))
    p.NumBytesThisRecord = 256 + len(body)
    raw[at:at + ping.NumBytesThisRecord] = bytes(p) + body
    path.write_bytes(bytes(raw))
    got, stats = _read(path)
    _same(got, tiles["high"])
    assert not stats.pings_dropped
    low = XtfReader(path, frequency="low")
    rows = sum(Tile.from_map(r.msg).rows for r in low if r.link == "sonar")
    assert low.stats.pings_dropped == {"no_range": 1} and rows == 2 * (ROWS - 1)


@pytest.mark.parametrize("value", [0, -5, "medium", float("nan"), float("inf"), True, ""])
def test_recording_frequency_key_is_checked(value):
    with pytest.raises(ConfigError, match="recording.frequency"):
        settings_from_dict({"recording": {"frequency": value}})


def test_recording_frequency_key_accepts_names_and_kilohertz(tmp_path):
    """Normalised as it is read: a name in lower case, kilohertz as a float, whether TOML gave
    a number or a string (a string is a name to every reader: "500" must not reach one)."""
    for value, want in (("low", "low"), ("HIGH", "high"), (455, 455.0), ("455", 455.0), (100.5, 100.5)):
        got = settings_from_dict({"recording": {"frequency": value}}).recording.frequency
        assert got == want and type(got) is type(want), value
    assert settings_from_dict({}).recording.frequency == "high"
    path, _ = dual_frequency_xtf(tmp_path)
    bad = settings_from_dict({"recording": {"frequency": "300"}}).recording.frequency
    with pytest.raises(LogFormatError, match="300 kHz"):
        check_positions([path], "", bad)


def test_convert_and_replay_take_the_option(tmp_path):
    path, tiles = dual_frequency_xtf(tmp_path)
    out = tmp_path / "low.atrlog"
    r = run_cli("convert", path, out, "--frequency", "low")
    assert r.returncode == 0, r.stderr
    assert "side-scan: 100 kHz (12) read, 500 kHz (12) not" in r.stdout
    got = {t.side: t for t in (Tile.from_map(x.msg) for x in read_atrlog(out) if x.link == "sonar")}
    _same(got, tiles["low"])
    for cmd in (["convert", path, tmp_path / "x.atrlog"], ["replay", path]):
        r = run_cli(*cmd, "--frequency", "300")
        assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "no side-scan channel at 300 kHz (--frequency)" in r.stderr
    assert not (tmp_path / "x.atrlog").exists()
    r = run_cli("replay", path, "--frequency", "0")
    assert r.returncode == 1 and r.stderr.strip().endswith("--frequency '0': expected high, low or a frequency in "
                                                           "kHz > 0"), r.stderr


@pytest.mark.parametrize("command", ["calibrate", "evaluate", "batch"])
def test_every_command_that_reads_xtf_takes_the_option(tmp_path, command):
    """The frequency reaches the reading of calibrate --input, evaluate --log and batch: a
    frequency the file lacks fails in one line before any output (exit 1)."""
    path, _ = dual_frequency_xtf(tmp_path)
    truth = tmp_path / "truth.csv"
    truth.write_text("lat_deg,lon_deg,shape\n48.0,-68.0,cylinder\n")
    out = tmp_path / "out"
    args = {"calibrate": ["calibrate", "--input", path, "--out", out / "m.json", "--no-progress"],
            "evaluate": ["evaluate", "--log", path, "--truth", truth, "--out", out],
            "batch": ["batch", path, "--contacts-out", out / "c.jsonl"]}[command]
    r = run_cli(*args, "--frequency", "300")
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "no side-scan channel at 300 kHz (--frequency)" in r.stderr
    assert not out.exists()
