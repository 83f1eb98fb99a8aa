"""Node building blocks: strip assembly with margins, nav merge, the ICD section 3 wire format."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage as ndi

from atr_node.node import wire
from atr_node.node.navmerge import NavMerger
from atr_node.node.publisher import Publisher, Subscriber
from atr_node.node.strip import StripAssembler
from atr_node.records import NavFix, NavTrack, Tile, TileNav


def strip_tiles(rows_per_tile, cols=40, seed=0, leg=1, side="stbd", t0=100.0):
    rng = np.random.default_rng(seed)
    total = sum(rows_per_tile)
    px = rng.random((total, cols), dtype=np.float32)
    t = t0 + 0.1 * np.arange(total)
    nav = np.stack([44 + 1e-6 * np.arange(total), np.full(total, 9.8), np.full(total, 10.0),
                    np.full(total, 14.0)], 1)
    tiles, start = [], 0
    for k, n in enumerate(rows_per_tile):
        sl = slice(start, start + n)
        tiles.append(Tile("m", leg, side, k, px[sl], "intensity", 1.0, 0.1, 0.1, False, t[sl],
                          nav=TileNav(*(nav[sl, c] for c in range(4)))))
        start += n
    return px, tiles


def window_max(px, m):
    """A stand-in detector that reads m rows on each side: max over a (2m+1) x 3 window."""
    return ndi.maximum_filter(np.nan_to_num(px, nan=-1), size=(2 * m + 1, 3), mode="constant", cval=-1)


@pytest.mark.parametrize("cuts", [[50], [7, 13, 30], [1, 1, 1, 47], [3, 40, 2, 5], [25, 25]])
@pytest.mark.parametrize("m", [0, 2, 5])
def test_cores_reproduce_the_whole_strip(cuts, m):
    px, tiles = strip_tiles(cuts)
    whole = window_max(px, m)
    asm = StripAssembler(m)
    got = np.full_like(whole, np.nan)
    row = 0
    units = [u for t in tiles for u in asm.push(t)] + asm.flush()
    for u in units:
        score = window_max(u.pixels, m)[u.core]
        got[row:row + u.core_rows] = score
        np.testing.assert_array_equal(u.ping_time[u.core], 100.0 + 0.1 * np.arange(row, row + u.core_rows))
        row += u.core_rows
    assert row == px.shape[0]
    np.testing.assert_array_equal(got, whole)


def test_new_leg_and_time_gap_start_new_strips():
    _, a = strip_tiles([10, 10], leg=1)
    _, b = strip_tiles([10], leg=2, t0=200.0)
    asm = StripAssembler(3)
    units = []
    for t in a + b:
        units += asm.push(t)
    units += asm.flush()
    legs = [(u.leg, u.core_rows) for u in units]
    assert sum(n for _, n in legs) == 30
    assert [lg for lg, _ in legs] == sorted(lg for lg, _ in legs)
    # the first unit of leg 2 has no context rows from leg 1
    first2 = next(u for u in units if u.leg == 2)
    assert first2.core.start == 0


def test_strip_state_round_trip():
    px, tiles = strip_tiles([12, 9, 14])
    a = StripAssembler(4)
    a.push(tiles[0])
    b = StripAssembler(4)
    b.restore(a.state())
    ua = a.push(tiles[1]) + a.push(tiles[2]) + a.flush()
    ub = b.push(tiles[1]) + b.push(tiles[2]) + b.flush()
    assert len(ua) == len(ub)
    for x, y in zip(ua, ub):
        np.testing.assert_array_equal(x.pixels, y.pixels)
        assert x.core == y.core


def test_navmerge_holds_until_nav_then_releases():
    track = NavTrack(max_gap_s=2.0)
    merger = NavMerger(track, max_gap_s=2.0)
    _, tiles = strip_tiles([5])
    tile = tiles[0].replace(nav=None)
    assert merger.push(tile, now=100.5) == []  # no INS yet: held
    assert merger.held == 1
    for t in np.arange(99.0, 100.6, 0.2):
        track.add(NavFix(t=float(t), lat_deg=44.0, lon_deg=9.8, heading_deg=0.0, altitude_m=14.0))
    out = merger.poll(now=100.6)
    assert len(out) == 1 and np.isfinite(out[0].pixels).all()
    assert merger.stats.pings_without_nav == 0


def test_navmerge_blanks_pings_when_ins_is_silent():
    track = NavTrack(max_gap_s=1.0)
    for t in (99.5, 99.9, 100.1):
        track.add(NavFix(t=t, lat_deg=44.0, lon_deg=9.8, heading_deg=0.0, altitude_m=14.0))
    merger = NavMerger(track, max_gap_s=1.0)
    _, tiles = strip_tiles([40])  # pings 100.0 .. 103.9; INS silent after 100.1
    assert merger.push(tiles[0].replace(nav=None), now=104.0) == []
    out = merger.poll(now=110.0)  # stale now: released
    assert len(out) == 1
    ok_rows = np.isfinite(out[0].pixels).any(axis=1)
    t = tiles[0].ping_time
    assert ok_rows[t <= 101.1].all() and not ok_rows[t > 101.1].any()
    assert merger.stats.pings_without_nav == int((t > 101.1).sum())


def test_slant_tile_gets_ground_axis_from_zero():
    track = NavTrack()
    merger = NavMerger(track)
    _, tiles = strip_tiles([4])
    tile = tiles[0].replace(slant=True, range0_m=0.0)
    out = merger.push(tile, now=0.0)
    assert out[0].range0_m == 0.0 and not out[0].slant
    assert out[0].cols == int(round(3.9 / 0.1)) + 1


# -- wire ----------------------------------------------------------------------------------

def contact(**kw):
    base = dict(id=3, state="new", t=1.7e9, lat_deg=44.1, lon_deg=9.8, east_m=5.0e5, north_m=4.88e6, sigma_m=1.2,
                bel=0.8, pl=0.9, m_theta=0.1, looks=2, detections=5, detectors=["mf", "z"], legs=[1, 2])
    base.update(kw)
    return wire.contact_message(**base)


def test_contact_and_heartbeat_validate_and_round_trip():
    c = contact()
    assert wire.validate_contact(c) == []
    hb = wire.heartbeat_message(t=1.0, uptime_s=2.0, tiles_in=3, tiles_done=2, tiles_dropped=0, tiles_rejected=1,
                                queue_depth=1, p50_ms=10.0, p99_ms=20.0, mode="nominal")
    assert wire.validate_heartbeat(hb) == []
    topic, back = wire.decode(wire.encode(wire.TOPIC_CONTACT, c))
    assert topic == "contact" and back == c


@pytest.mark.parametrize("change,fragment", [
    ({"bel": 0.95}, "bel <= pl"),
    ({"state": "gone"}, "state"),
    ({"m_theta": 0.5}, "m_theta"),
    ({"lat_deg": 95.0}, "WGS84"),
])
def test_bad_contacts_are_refused(change, fragment):
    with pytest.raises(ValueError, match=fragment):
        contact(**change)


def test_validate_catches_types_and_extra_keys():
    c = contact()
    c2 = dict(c, looks=2.0)
    assert any("looks" in p for p in wire.validate_contact(c2))
    c3 = dict(c, colour="red")
    assert any("unexpected" in p for p in wire.validate_contact(c3))
    c4 = {k: v for k, v in c.items() if k != "pl"}
    assert any("missing 'pl'" in p for p in wire.validate_contact(c4))


def test_publisher_to_subscriber_on_loopback():
    pub = Publisher("tcp://127.0.0.1:*")
    sub = Subscriber(pub.endpoint)
    try:
        got = None
        for _ in range(50):  # slow joiner: resend until the subscription is up
            pub.contact(contact())
            got = sub.recv(timeout_s=0.1)
            if got:
                break
        assert got is not None
        topic, msg = got
        assert topic == "contact" and wire.validate_contact(msg) == []
    finally:
        sub.close()
        pub.close()
