"""EdgeTech JSF: hand-packed messages at the specification's offsets, round trips of a simulated
mission through our writer, and damaged files. No real JSF file is shared with the project:
every file here is generated (see docs/xtf.md)."""

from __future__ import annotations

import logging
import math
import struct

import numpy as np
import pytest

from atr_node.cli import main
from atr_node.errors import LogFormatError
from atr_node.io.atrlog import read_atrlog
from atr_node.io.jsf import JsfReader, JsfStats, iter_jsf_items, iter_jsf_records
from atr_node.io.jsf_write import JsfWriter, write_jsf
from atr_node.io.xtf_packets import KNOT_M_S, XtfNav, XtfPing, XtfSerial
from atr_node.io.recording import open_recording
from atr_node.records.tile import Tile

from .conftest import T0, make_tile

T_PING = 1_700_000_123  # 2023-11-14 22:15:23 UTC


def spec_ping(*, channel: int, samples: bytes, n: int, data_format: int = 0, weighting: int = 3,
              ping_number: int = 7, validity: int = 0b0100_0010_0100_1101, units: int = 2,
              x: int = round(-68.5 * 600000), y: int = round(48.25 * 600000), ms: int = 456) -> bytes:
    """One message 80 packed with ``struct`` at the byte offsets of the JSF description (rev
    1.20 / rev M), independently of the reader's field table."""
    h = bytearray(240)
    struct.pack_into("<i", h, 0, T_PING)                                  # ping time, s since 1970
    struct.pack_into("<I", h, 4, 10)                                      # starting depth, samples
    struct.pack_into("<I", h, 8, ping_number)
    struct.pack_into("<H", h, 16, 0x0001)                                 # MSB: start freq bit 16
    struct.pack_into("<H", h, 20, 7)                                      # LSB2: speed 1/100 kn
    struct.pack_into("<h", h, 28, 1)                                      # ID code
    struct.pack_into("<H", h, 30, validity)
    struct.pack_into("<h", h, 34, data_format)
    struct.pack_into("<ii", h, 80, x, y)                                  # X (lon), Y (lat)
    struct.pack_into("<h", h, 88, units)
    struct.pack_into("<H", h, 114, n)
    struct.pack_into("<I", h, 116, 20_000)                                # sample interval, ns
    struct.pack_into("<HH", h, 126, 0xD4C0, 60_000)                       # 120 000 and 60 000 daHz
    struct.pack_into("<i", h, 136, 12_000)                                # depth, mm
    struct.pack_into("<i", h, 144, 4_250)                                 # altitude, mm
    struct.pack_into("<f", h, 148, 1480.0)                                # sound speed
    struct.pack_into("<hh", h, 156, 2023, 318)                            # year, day
    struct.pack_into("<h", h, 168, weighting)
    struct.pack_into("<H", h, 172, 12_345)                                # heading, 1/100 deg
    struct.pack_into("<hhh", h, 186, 22, 15, 22)                          # fix time 22:15:22
    struct.pack_into("<h", h, 194, 35)                                    # speed, 1/10 kn
    struct.pack_into("<I", h, 200, (T_PING % 86400) * 1000 + ms)          # ms today
    struct.pack_into("<H", h, 220, 1)                                     # packet number
    body = bytes(h) + samples
    return struct.pack("<HBBHBBBBHi", 0x1601, 10, 0, 80, 0, 21, channel, 0, 0, len(body)) + body


def test_a_hand_packed_ping_reads_as_the_specification_says(tmp_path):
    env = np.array([0, 8, 16, 65535, 24, 32, 40, 48], dtype="<u2")
    iq = np.array([[3, 4], [-6, 8], [0, -1], [5, 12], [0, 0], [-8, -6], [1, 0], [0, 2]], dtype="<i2")
    path = tmp_path / "spec.jsf"
    path.write_bytes(spec_ping(channel=0, samples=env.tobytes(), n=8)
                     + spec_ping(channel=1, samples=iq.tobytes(), n=8, data_format=1, weighting=-1))
    stats = JsfStats()
    items = list(iter_jsf_items(path, stats))
    assert len(items) == 1 and isinstance(items[0], XtfPing)
    ping = items[0]
    nav = ping.nav
    assert nav.t == T_PING + 0.456
    assert nav.lat_deg == pytest.approx(48.25, abs=1e-12) and nav.lon_deg == pytest.approx(-68.5, abs=1e-12)
    assert nav.heading_deg == pytest.approx(123.45) and nav.altitude_m == 4.25 and nav.depth_m == 12.0
    assert nav.speed_m_s == pytest.approx(3.57 * KNOT_M_S)
    assert nav.fix_t == T_PING - 1.0
    assert ping.ping_number == 7 and set(ping.channels) == {"port", "stbd"}
    port, stbd = ping.channels["port"], ping.channels["stbd"]
    np.testing.assert_array_equal(port.samples, env / 8.0)  # weighting 3: x 2^-3
    np.testing.assert_allclose(stbd.samples, np.hypot(iq[:, 0], iq[:, 1]) * 2.0, rtol=1e-6)  # weighting -1
    dr = 1480.0 * 20e-6 / 2.0
    assert port.dr_m == pytest.approx(dr) and port.range0_m == pytest.approx(10.5 * dr)
    assert port.frequency_hz == pytest.approx(5.0 * (120_000 + 60_000))
    assert port.bandwidth_hz * 1e3 == pytest.approx(600_000.0)  # kHz in XtfChannel, as XTF's
    assert stats.packets["sonar"] == 2 and not stats.errors


def test_validity_flags_and_coordinate_units_decide_what_is_used(tmp_path):
    env = np.arange(1, 9, dtype="<u2").tobytes()
    # position and altitude not flagged valid: no position, no altitude; heading still flagged
    path = tmp_path / "flags.jsf"
    path.write_bytes(spec_ping(channel=1, samples=env, n=8, validity=0b1000))
    (ping,) = iter_jsf_items(path, JsfStats())
    assert math.isnan(ping.nav.lat_deg) and math.isnan(ping.nav.altitude_m) and ping.nav.heading_deg == 123.45
    # units 3 (X, Y in dm, projected): refused without a CRS (one line naming --crs:
    # test_reading_robustness.py); used with one
    path.write_bytes(b"".join(spec_ping(channel=1, samples=env, n=8, units=3, ping_number=k, x=5_000_000,
                                        y=50_000_000) for k in range(3)))
    with pytest.raises(LogFormatError, match="--crs"):
        list(iter_jsf_items(path, JsfStats()))
    records = list(JsfReader(path, crs="EPSG:32619", altitude="altimeter"))
    tile = Tile.from_map(next(r.msg for r in records if r.link == "sonar"))
    # UTM 19N, E 500 000 m (the central meridian, 69 W), N 5 000 000 m: 45.1 N (pyproj)
    assert tile.nav.lon_deg[0] == pytest.approx(-69.0, abs=1e-9) and 45.1 < tile.nav.lat_deg[0] < 45.2


def _tiles(records) -> list[Tile]:
    return [Tile.from_map(r.msg) for r in records if r.link == "sonar"]


def _stack(tiles, side, get):
    return np.concatenate([get(t) for t in tiles if t.side == side])


@pytest.mark.parametrize("data_format", ["envelope", "analytic"])
def test_simulated_mission_round_trips_within_the_format_resolution(small_mission, tmp_path, data_format):
    _, _, files = small_mission
    records = list(read_atrlog(files.atrlog))
    tiles = _tiles(records)
    path = tmp_path / "sim.jsf"
    ws = write_jsf(path, records, data_format=data_format)
    assert ws.tiles == 36 and ws.unpaired_tiles == 0 and ws.skipped["can"] > 0
    stats = JsfStats()
    back_records = list(iter_jsf_records(path, tile_pings=128, altitude="altimeter", stats=stats))
    back = _tiles(back_records)
    assert stats.pings == sum(t.rows for t in tiles) // 2 and not stats.errors and not stats.pings_dropped
    nmea_in = [bytes(r.msg).rstrip(b"\r\n") for r in records if r.link == "nmea"]
    assert stats.nmea["raw_serial"] == len(nmea_in)
    assert [bytes(r.msg).rstrip(b"\r\n") for r in back_records if r.link == "nmea"][:5] == nmea_in[:5]
    for side in ("port", "stbd"):
        a = _stack(tiles, side, lambda t: t.pixels)
        b = _stack(back, side, lambda t: t.pixels)
        assert a.shape == b.shape
        # per ping: 2^-N with N the largest weighting keeping the brightest sample in range
        limit = 65535.0 if data_format == "envelope" else 32767.0
        peak = np.nan_to_num(a).max(axis=1)
        with np.errstate(divide="ignore"):
            n = np.where(peak > 0, np.clip(np.floor(np.log2(limit / peak)), -16, 15), 0)
        step = 2.0 ** -n  # no data (NaN) is written as 0 and comes back as 0
        tol = (0.5 if data_format == "envelope" else 0.75) * step[:, None] + 1e-6 * np.abs(np.nan_to_num(a))
        assert np.all(np.abs(np.nan_to_num(a) - b) <= tol)
        np.testing.assert_allclose(_stack(back, side, lambda t: t.ping_time),
                                   _stack(tiles, side, lambda t: t.ping_time), rtol=0, atol=0.5e-3)
        for k, res in (("lat_deg", 0.5 / 600000), ("lon_deg", 0.5 / 600000), ("heading_deg", 0.005),
                       ("altitude_m", 0.0005)):
            np.testing.assert_allclose(_stack(back, side, lambda t: getattr(t.nav, k)),
                                       _stack(tiles, side, lambda t: getattr(t.nav, k)), rtol=0, atol=res + 1e-9)
    for t in back:
        ref = tiles[0]
        assert t.dr_m == pytest.approx(ref.dr_m, rel=1e-5)  # 1 ns of a 133 us interval
        assert abs(t.range0_m - ref.range0_m) <= ref.dr_m / 2 + 1e-9  # start depth: whole samples
        assert t.dx_m == pytest.approx(ref.dx_m, abs=0.005 * KNOT_M_S * 0.05 + 1e-6)  # speed: 1/100 kn
        assert t.sensor.frequency_hz == ref.sensor.frequency_hz and t.sensor.bandwidth_hz == ref.sensor.bandwidth_hz


def _write_small(path, **kwargs):
    tiles = [make_tile(side, rows=6, cols=10, dr_m=0.05, range0_m=0.025) for side in ("port", "stbd")]
    with JsfWriter(path, **kwargs) as w:
        for t in tiles:
            w.write_tile(t)
    return tiles


def test_unknown_messages_other_subsystems_and_nav_messages(tmp_path):
    path = tmp_path / "mixed.jsf"
    t_nav = int(T0) + 1
    with JsfWriter(path, subsystem=21) as w:
        w.write_message(182, bytes(24))                                  # system information
        w.write_message(9999, b"\x55" * 37)                              # nobody's type
        w.write_message(80, bytes(240), subsystem=0)                     # sub-bottom ping
        w.write_nmea(t_nav + 0.25, b"$GPZDA,221523.00,14,11,2023,00,00*6E\r\n")
        pr = bytearray(44)
        struct.pack_into("<ii", pr, 0, t_nav, 500)
        struct.pack_into("<Hi", pr, 34, 27_000, 1 << 9)                  # heading 270 deg, valid
        w.write_message(2020, bytes(pr))
        dvl = bytearray(72)
        struct.pack_into("<ii4xI", dvl, 0, t_nav, 600, (1 << 6) | (1 << 31))  # heading flagged, error bit
        w.write_message(2080, bytes(dvl))
        struct.pack_into("<ii4xI", dvl, 0, t_nav, 650, 1 << 6)
        struct.pack_into("<H", dvl, 50, 4_500)                           # heading 45 deg
        w.write_message(2080, bytes(dvl))
        sit = bytearray(100)
        struct.pack_into("<ii4xI", sit, 0, t_nav, 700, 0b100_0001_0110)   # lon, lat, altitude, heading
        struct.pack_into("<dd", sit, 28, 48.5, -68.25)
        struct.pack_into("<ff", sit, 44, 0.0, 6.5)
        struct.pack_into("<f", sit, 76, 91.5)
        w.write_message(2091, bytes(sit))
        for t in [make_tile(s, rows=3, cols=8) for s in ("port", "stbd")]:
            w.write_tile(t)
    with JsfWriter(tmp_path / "lf.jsf", subsystem=20) as w2:
        for t in [make_tile(s, rows=3, cols=8) for s in ("port", "stbd")]:
            w2.write_tile(t)
    path.write_bytes(path.read_bytes() + (tmp_path / "lf.jsf").read_bytes())
    stats = JsfStats()
    items = list(iter_jsf_items(path, stats))
    assert stats.skipped == {"system_info": 1, "unknown_9999": 1, "sonar_subsystem_0": 1, "sonar_subsystem_20": 6}
    assert stats.packets["sonar"] == 13 and not stats.errors
    serial = [i for i in items if isinstance(i, XtfSerial)]
    assert serial[0].lines == (b"$GPZDA,221523.00,14,11,2023,00,00*6E",) and serial[0].t == t_nav + 0.25
    navs = [i for i in items if isinstance(i, XtfNav)]
    assert [(n.source, n.heading_deg) for n in navs] == [("jsf:pitch_roll", 270.0), ("jsf:dvl", 45.0),
                                                             ("jsf:situation", 91.5)]
    assert (navs[2].lat_deg, navs[2].lon_deg, navs[2].altitude_m, navs[2].t) == (48.5, -68.25, 6.5, t_nav + 0.7)
    assert math.isnan(navs[2].depth_m)  # depth not flagged
    assert sum(isinstance(i, XtfPing) for i in items) == 3
    lf = [i for i in iter_jsf_items(path, JsfStats(), subsystem=20) if isinstance(i, XtfPing)]
    assert len(lf) == 3
    records = list(JsfReader(path))
    kinds = [bytes(r.msg)[3:6] for r in records if r.link == "nmea"]
    assert b"ZDA" in kinds and b"HDT" in kinds and b"GGA" in kinds


def test_a_truncated_file_keeps_everything_before_the_cut(tmp_path, caplog):
    path = tmp_path / "cut.jsf"
    _write_small(path)
    data = path.read_bytes()
    one = 16 + 240 + 2 * 10
    cut = 7 * one + 100  # inside the 8th message: 3 whole pings, the 4th has its port side only
    path.write_bytes(data[:cut])
    stats = JsfStats()
    with caplog.at_level(logging.WARNING, logger="atr_node.io.jsf"):
        tiles = _tiles(iter_jsf_records(path, stats=stats))
    assert stats.truncated and len(stats.errors) == 1 and f"at byte {7 * one}:" in stats.errors[0]
    assert len([r for r in caplog.records if r.levelno == logging.WARNING]) == 1
    # the 4th ping has lost its starboard side: a tile of its own (the channels changed)
    assert [(t.side, t.rows) for t in tiles] == [("port", 3), ("stbd", 3), ("port", 1)]
    # a broken start marker further in ends the read the same way
    path.write_bytes(data[:3 * one] + b"\x00\x00" + data[3 * one + 2:])
    stats = JsfStats()
    tiles = _tiles(iter_jsf_records(path, stats=stats))
    assert "at byte 828: message start marker 0x0000" in stats.errors[0]
    assert sum(t.rows for t in tiles if t.side == "port") == 2


def test_a_file_that_is_not_jsf_is_one_line_and_exit_1(tmp_path, capsys):
    bad = tmp_path / "notes.jsf"
    bad.write_bytes(b"this is a text file, not sonar data\n" * 3)
    with pytest.raises(LogFormatError, match=r"notes.jsf at byte 0: not a JSF file: start marker 0x6874"):
        JsfReader(bad)
    empty = tmp_path / "empty.jsf"
    empty.write_bytes(b"")
    with pytest.raises(LogFormatError, match="0 bytes"):
        open_recording(empty)
    assert main(["convert", str(bad), str(tmp_path / "out.atrlog")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a JSF file" in err and not (tmp_path / "out.atrlog").exists()
    assert main(["replay", str(bad), "--publish", "none", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a JSF file" in err


def test_convert_and_replay_accept_jsf(tmp_path, capsys):
    path = tmp_path / "small.jsf"
    tiles = _write_small(path, data_format="analytic")
    out = tmp_path / "small.atrlog"
    assert main(["convert", str(path), str(out), "--mission", "m1", "--leg", "4", "--subsystem", "21"]) == 0
    text = capsys.readouterr().out
    assert "sonar 12" in text and "pings 6, tiles 2" in text
    back = _tiles(read_atrlog(out))
    assert [(t.mission, t.leg, t.side, t.shape) for t in back] == [("m1", 4, s, (6, 10)) for s in ("port", "stbd")]
    assert [r.t for r in open_recording(path)] == [r.t for r in iter_jsf_records(path)]
    assert main(["replay", str(path), "--publish", "none", "--quiet", "--workers", "0",
                 "--online-calibration", "off"]) == 0
    assert "2 tiles in, 2 done, 0 rejected" in capsys.readouterr().err
    assert main(["convert", str(out), str(tmp_path / "x.jsf")]) == 1
    assert "JSF is read only" in capsys.readouterr().err
    assert tiles[0].rows == 6


def test_calibrate_takes_a_jsf_recording(tmp_path):
    """calibrate --input survey.jsf reads its tiles as replay does (it was taken for a picture:
    "not a picture OpenCV can read"); the images are intensity, as the node scores them."""
    from atr_node.calibration.sources import images_from_paths
    from atr_node.config import Settings

    path = tmp_path / "small.jsf"
    _write_small(path, data_format="analytic")
    imgs = images_from_paths([path], settings=Settings(), max_images=4, pixel_m=None, range0_m=None)
    tiles = _tiles(iter_jsf_records(path))
    assert len(imgs) == 2 == len(tiles)
    for im, t in zip(imgs, tiles):
        assert im.name == t.ident
        want = t.as_intensity().ground_range().pixels if t.slant else t.as_intensity().pixels
        np.testing.assert_array_equal(im.pixels, want)


def test_frequency_of_xtf_files_is_not_silently_ignored_on_jsf(tmp_path, caplog):
    """--frequency picks XTF channels; a JSF file says how its subsystem is chosen instead."""
    path = tmp_path / "small.jsf"
    _write_small(path, data_format="analytic")
    with caplog.at_level(logging.WARNING):
        low = [r.t for r in open_recording(path, frequency="low")]
    assert low == [r.t for r in iter_jsf_records(path)]  # read as before
    (rec,) = [r for r in caplog.records if "--frequency" in r.getMessage()]
    assert "--subsystem" in rec.getMessage()
    caplog.clear()
    other = tmp_path / "other.jsf"
    _write_small(other, data_format="analytic")
    assert main(["convert", str(other), str(tmp_path / "s.atrlog"), "--frequency", "low"]) == 0
    assert sum("--subsystem" in r.getMessage() for r in caplog.records) == 1  # checked, then read: said once
    caplog.clear()
    list(open_recording(path))
    assert not [r for r in caplog.records if "--frequency" in r.getMessage()]


def test_long_pings_msb_sample_count_and_multi_packet_pings(tmp_path):
    # > 65535 samples: bits 16-19 of the count in the MSB word; uint16 pixels come back exactly
    tiles = [make_tile(s, rows=2, cols=70_000, dr_m=0.01, range0_m=0.005) for s in ("port", "stbd")]
    with JsfWriter(tmp_path / "long.jsf") as w:
        for t in tiles:
            w.write_tile(t)
    back = _tiles(iter_jsf_records(tmp_path / "long.jsf", altitude="altimeter"))
    for a, b in zip(tiles, back):
        assert b.shape == (2, 70_000)
        np.testing.assert_array_equal(b.pixels, np.nan_to_num(a.pixels))
    # a ping split over two packets (packet number 1, 2) of the same channel: samples continue
    first = np.arange(1, 9, dtype="<u2")
    second = np.arange(100, 104, dtype="<u2")
    two = bytearray(spec_ping(channel=0, samples=second.tobytes(), n=4, weighting=0))
    struct.pack_into("<H", two, 16 + 220, 2)
    (tmp_path / "split.jsf").write_bytes(spec_ping(channel=0, samples=first.tobytes(), n=8, weighting=0) + bytes(two))
    (ping,) = iter_jsf_items(tmp_path / "split.jsf", JsfStats())
    np.testing.assert_array_equal(ping.channels["port"].samples, np.concatenate([first, second]))
