"""Replay, pacing, recorder, multiplexer and the hardware-in-the-loop outputs, end to end."""

from __future__ import annotations

import threading
import uuid
from pathlib import Path

import numpy as np
import pytest

import hw
from atr_node.io.atrlog import AtrLogWriter, LogRecord, read_atrlog
from atr_node.records.tile import Tile
from hw.can_link import CanLink
from hw.can_nav import encode_altitude, encode_attitude, encode_leg, encode_position, encode_time
from hw.decode import NavDecoder
from hw.hil import CanBusOut, HilPlayer, PtyNmeaOut, ZmqTileOut
from hw.nmea import encode_dpt, encode_gga, encode_hdt, encode_zda
from hw.nmea_decoder import NmeaDecoder
from hw.recorder import LinkMux, RecordingLink
from hw.replay import Paced, ReplayLink, StampedNmeaLink, TimeMerge
from hw.serial_nmea import SerialNmeaLink
from hw.zmq_sonar import ZmqTileLink

T0 = 1.7e9


def tile_map(seq: int, rng: np.random.Generator) -> dict:
    pixels = rng.random((8, 16), dtype=np.float32)
    pixels[0, :3] = np.nan
    t = Tile(mission="hil", leg=1, side="port", seq=seq, pixels=pixels, kind="intensity", range0_m=5.0,
             dr_m=0.05, dx_m=0.05, slant=False, ping_time=T0 + seq + np.arange(8) * 0.025)
    return t.to_map()


def can_msg(frame: tuple[int, bytes, bool]) -> dict:
    return {"id": frame[0], "data": frame[1], "ext": frame[2]}


@pytest.fixture
def mission_log(tmp_path: Path, rng: np.random.Generator) -> tuple[Path, list[LogRecord]]:
    """A small recorded mission: NMEA, CAN and sonar records interleaved, one garbage line."""
    recs: list[LogRecord] = []
    for k in range(40):
        t = T0 + 0.1 * k
        lat, lon = 44.08 + 1e-6 * k, 9.85
        recs.append(LogRecord(t, "nmea", encode_zda(t).rstrip() if k % 10 == 0 else encode_gga(t, lat, lon).rstrip()))
        recs.append(LogRecord(t + 0.01, "nmea", encode_hdt(90.0 + k).rstrip()))
        recs.append(LogRecord(t + 0.02, "can", can_msg(encode_time(t + 0.02) if k % 10 == 0 else encode_position(lat, lon))))
        recs.append(LogRecord(t + 0.03, "can", can_msg(encode_attitude(90.0 + k, speed_m_s=2.0))))
        recs.append(LogRecord(t + 0.04, "can", can_msg(encode_altitude(10.0 + 0.01 * k))))
        if k % 10 == 5:
            recs.append(LogRecord(t + 0.05, "sonar", tile_map(k // 10, rng)))
            recs.append(LogRecord(t + 0.06, "can", can_msg(encode_leg(1 + k // 20))))
            recs.append(LogRecord(t + 0.07, "nmea", encode_dpt(9.5).rstrip()))
    recs.insert(7, LogRecord(T0 + 0.15, "nmea", b"$GPHDT,12*ZZ"))
    path = tmp_path / "mission.atrlog"
    with AtrLogWriter(path) as w:
        for r in recs:
            w.write_record(r)
    return path, recs


def same(a: LogRecord, b: LogRecord) -> bool:
    return (a.t, a.link, a.msg) == (b.t, b.link, b.msg)


def test_replay_yields_the_recorded_records_unchanged(mission_log):
    path, recs = mission_log
    with hw.open_link(str(path), speed="max") as link:
        got = list(link)
        assert link.at_end
    assert len(got) == len(recs) and all(same(a, b) for a, b in zip(got, recs))
    with ReplayLink(path, links=["can"]) as can_only:
        assert [r.msg for r in can_only] == [r.msg for r in recs if r.link == "can"]


def test_truncated_recording_replays_everything_before_the_cut(mission_log, tmp_path):
    path, recs = mission_log
    cut = tmp_path / "cut.atrlog"
    data = path.read_bytes()
    cut.write_bytes(data[:len(data) - 5])
    with ReplayLink(cut) as link:
        got = list(link)
        assert link.at_end
    assert len(got) == len(recs) - 1 and all(same(a, b) for a, b in zip(got, recs))


def test_pacing_holds_a_record_until_due_and_shortens_long_gaps(tmp_path):
    path = tmp_path / "gap.atrlog"
    with AtrLogWriter(path) as w:
        w.write(T0, "nmea", b"$A")
        w.write(T0 + 1000.0, "nmea", b"$B")  # 1000 s later in the log
    with Paced(ReplayLink(path), 1.0) as paced:
        assert paced.recv(timeout=1.0).msg == b"$A"
        assert paced.recv(timeout=0.05) is None  # $B is due in 1000 s: held, not lost
        assert not paced.at_end
    with Paced(ReplayLink(path), 1.0, max_gap_s=0.0) as paced:
        assert [r.msg for r in paced] == [b"$A", b"$B"]
    with Paced(ReplayLink(path), 1e6) as paced:  # a factor: 1000 s of log in 1 ms
        assert [r.msg for r in paced] == [b"$A", b"$B"]
    with pytest.raises(hw.LinkSpecError):
        Paced(ReplayLink(path), 0.0)


def test_recorder_writes_what_it_delivers(mission_log, tmp_path):
    path, recs = mission_log
    out = tmp_path / "rec.atrlog"
    with RecordingLink(ReplayLink(path), out) as rec_link:
        delivered = list(rec_link)
    again = list(read_atrlog(out))
    assert len(again) == len(delivered) == len(recs)
    assert all(same(a, b) for a, b in zip(again, recs))


def test_mux_merges_links_and_ends_when_all_end(mission_log):
    path, recs = mission_log
    with LinkMux([ReplayLink(path, links=["nmea"]), ReplayLink(path, links=["can", "sonar"])]) as mux:
        got = list(mux)
        assert mux.at_end
    for kind in ("nmea", "can", "sonar"):  # order within each link is kept
        assert [r.msg for r in got if r.link == kind] == [r.msg for r in recs if r.link == kind]


def test_hil_replay_out_to_pty_virtual_can_and_zmq(mission_log, tmp_path):
    """The recording played onto real transports comes back identical through the node's drivers."""
    path, recs = mission_log
    channel = f"hil-{uuid.uuid4().hex}"
    pty_out, can_out, zmq_out = PtyNmeaOut(), CanBusOut("virtual", channel), ZmqTileOut("tcp://127.0.0.1:*")
    node = LinkMux([SerialNmeaLink(pty_out.slave_path), CanLink("virtual", channel), ZmqTileLink(zmq_out.endpoint)])
    recorded = tmp_path / "node.atrlog"
    player = HilPlayer(Paced(ReplayLink(path), None), nmea=pty_out, can=can_out, sonar=zmq_out)
    th = threading.Thread(target=player.run, daemon=True)
    try:
        with RecordingLink(node, recorded) as node_in:
            th.start()
            got = []
            while len(got) < len(recs) and (rec := node_in.recv(timeout=5.0)) is not None:
                got.append(rec)
            th.join(timeout=10)
    finally:
        player.close()
    assert not player.counts.get("nmea_dropped") and not player.counts.get("sonar_dropped")
    assert len(got) == len(recs)
    for kind in ("nmea", "can", "sonar"):
        assert [r.msg for r in got if r.link == kind] == [r.msg for r in recs if r.link == kind], kind
    tiles = [Tile.from_map(r.msg) for r in got if r.link == "sonar"]
    assert [t.seq for t in tiles] == [0, 1, 2, 3]
    assert np.array_equal(tiles[0].pixels, Tile.from_map(recs[[r.link for r in recs].index("sonar")].msg).pixels,
                          equal_nan=True)
    # the node's recording holds the same messages, and decodes to the same navigation
    assert sorted(map(repr, (r.msg for r in read_atrlog(recorded)))) == sorted(map(repr, (r.msg for r in recs)))
    direct, via = NavDecoder(), NavDecoder()
    n_direct = sum(len(direct.feed(r)) for r in recs)
    n_via = sum(len(via.feed(r)) for r in got)
    assert n_direct == n_via and direct.stats()["nmea"] == via.stats()["nmea"]
    assert direct.nmea.counts["bad_checksum"] == 1


def test_real_nmea_logs_through_a_pty(real_data):
    """R/V Palmer sentences (openrvdas NBP1406) written to a pty and read back by the serial driver."""
    paths = sorted((real_data / "nmea").glob("NBP1406_*"))
    assert len(paths) == 3
    direct = NmeaDecoder()
    sentences = []
    for p in paths:
        with StampedNmeaLink(p) as src:
            for r in src:
                sentences.append(r.msg)
                direct.feed(r.msg, r.t)
            assert src.counts["bad_lines"] == 0
    out = PtyNmeaOut()
    link = SerialNmeaLink(out.slave_path)
    player = HilPlayer(LinkMux([StampedNmeaLink(p) for p in paths]), nmea=out)
    th = threading.Thread(target=player.run, daemon=True)
    th.start()
    via = NmeaDecoder()
    got = []
    try:
        while len(got) < len(sentences) and (rec := link.recv(timeout=5.0)) is not None:
            got.append(rec.msg)
            via.feed(rec.msg, rec.t)
        th.join(timeout=10)
    finally:
        link.shutdown()
        player.close()
    assert sorted(got) == sorted(sentences) and len(got) == 15000
    assert via.counts == direct.counts
    assert via.counts["accepted"] == 12858 and via.counts["unsupported"] == 2142 and via.rejected == 2142
    assert dict(via.by_type) == {"HDT": 5714, "DPT": 5000, "ZDA": 715, "GGA": 715, "VTG": 714}


def test_time_merge_orders_recordings_by_time(tmp_path):
    a, b = tmp_path / "a.atrlog", tmp_path / "b.atrlog"
    with AtrLogWriter(a) as wa, AtrLogWriter(b) as wb:
        for k in range(50):
            wa.write(T0 + 0.3 * k, "nmea", b"$A%d" % k)
            wb.write(T0 + 0.7 * k, "can", {"id": k, "data": b"", "ext": False})
    with TimeMerge([ReplayLink(a), ReplayLink(b)]) as merged:
        got = list(merged)
    assert len(got) == 100
    assert [r.t for r in got] == sorted(r.t for r in got)
    assert [r.msg for r in got if r.link == "can"] == [{"id": k, "data": b"", "ext": False} for k in range(50)]


def test_open_link_recording_specs_and_pacing_options(mission_log):
    path, recs = mission_log
    with hw.open_link(f"replay:{path}?speed=max&links=can") as link:
        assert isinstance(link, Paced) and link.speed is None
    with hw.open_link(f"replay://{path}", speed=3) as link:
        assert link.speed == 3.0 and link.recv(timeout=1.0).msg == recs[0].msg
    with pytest.raises(hw.LinkSpecError, match="speed"):
        hw.open_link(str(path), speed="fast")
    with pytest.raises(hw.LinkSpecError, match="missing"):
        hw.open_link("nmea")


def test_tools_smoke(mission_log, tmp_path, real_data, capsys):
    import importlib.util
    tools = Path(__file__).resolve().parents[2] / "tools"

    def load(name):
        spec = importlib.util.spec_from_file_location(name.replace("/", "_"), tools / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    out = tmp_path / "converted.atrlog"
    assert load("record_links").main([str(out), f"candump:{real_data / 'can' / 'candumpSample3.txt'}?speed=max",
                                      f"stamped:{real_data / 'nmea' / 'NBP1406_mbdp-2014-08-01'}?speed=max"]) == 0
    conv = list(read_atrlog(out))
    assert len(conv) == 2368 + 5000 and [r.t for r in conv] == sorted(r.t for r in conv)
    path, recs = mission_log
    assert load("hil_player").main([str(path), "--speed", "max", "--no-sonar", "--can-channel",
                                    f"smoke-{uuid.uuid4().hex}", "--max-records", "20"]) == 0
    assert "nmea_url" in capsys.readouterr().out
    assert load("bench/ingest").main(["links", "--quick", "--real-data", str(real_data)]) == 0
    assert "| replay max |" in capsys.readouterr().out


def test_iter_link_wraps_any_record_iterable(mission_log):
    from hw.replay import IterLink

    path, recs = mission_log
    with Paced(IterLink(read_atrlog(path), name="gen"), None) as link:
        got = list(link)
        assert link.at_end
    assert len(got) == len(recs) and all(same(a, b) for a, b in zip(got, recs))


def test_mux_keeps_going_when_one_link_fails(mission_log):
    """A serial port whose other end disappears (no reconnect) fails; the other links go on."""
    import os

    path, recs = mission_log
    master, slave = os.openpty()
    serial_link = SerialNmeaLink(os.ttyname(slave))
    os.close(master)  # the device goes away: the next read fails with an I/O error
    try:
        with LinkMux([serial_link, ReplayLink(path, links=["nmea"])]) as mux:
            got = list(mux)
            assert mux.counts[f"failed:{serial_link.name}"] == 1 and "read failed" in mux.last_reject
    finally:
        os.close(slave)
    assert [r.msg for r in got] == [r.msg for r in recs if r.link == "nmea"]
