"""``--crs``: XTF positions in projected metres (NavUnits 0), ICD v1.1 section 6.

The projected files are made by the project's own writer from the tiles of the real Iver2
recording (``XtfWriter(path, crs=...)``), next to a lat/lon file of the same tiles, so the
two must give the same tiles, the same nav and the same contacts.
"""

from __future__ import annotations

import json
import logging
import math
import struct

import numpy as np
import pytest
from pyxtf.xtf_ctypes import XTFFileHeader, XTFPingHeader
from scipy.integrate import quad

from atr_node.calibration.sources import images_from_paths
from atr_node.cli import main
from atr_node.config import Settings
from atr_node.errors import ConfigError, LogFormatError
from atr_node.io.crs import projection
from atr_node.io.xtf import XtfReader
from atr_node.io.xtf_write import XtfWriter
from atr_node.records.tile import Tile

from .conftest import run_cli

UTM19 = "EPSG:32619"  # the Iver2 recording is at 68.8 W: UTM zone 19 north
NAV_UNITS_AT = 164  # byte offset of XTFFileHeader.NavUnits


@pytest.fixture(scope="module")
def pair(iver2, tmp_path_factory):
    """(lat/lon XTF, projected XTF in UTM 19N) of the same tiles, written by XtfWriter."""
    d = tmp_path_factory.mktemp("crs")
    tiles = [Tile.from_map(r.msg) for r in XtfReader(iver2) if r.link == "sonar"]
    paths = (d / "latlon.xtf", d / "utm19.xtf")
    for path, crs in zip(paths, ("", UTM19)):
        with XtfWriter(path, crs=crs) as w:
            for t in tiles:
                w.write_tile(t)
    return paths


def _tiles(path, **kw):
    return [Tile.from_map(r.msg) for r in XtfReader(path, **kw) if r.link == "sonar"]




# -- the projection against an independent reference -----------------------------------------

def _meridian_arc_m(lat_deg: float) -> float:
    """Length of the WGS 84 meridian from the equator: the integral of the meridian radius of
    curvature M = a (1 - e^2) / (1 - e^2 sin^2 phi)^(3/2)."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    return quad(lambda p: a * (1 - e2) / (1 - e2 * math.sin(p) ** 2) ** 1.5, 0.0, math.radians(lat_deg),
                epsabs=1e-9)[0]


@pytest.mark.parametrize("lat_deg", [0.0, 12.5, 48.4457, 71.0])
def test_utm_on_the_central_meridian_is_the_scaled_meridian_arc(lat_deg):
    # on the central meridian (69 W for zone 19) UTM is E = 500 000 m, N = k0 x meridian arc
    p = projection(UTM19)
    east_m, north_m = p.from_latlon(lat_deg, -69.0)
    assert east_m == pytest.approx(500000.0, abs=1e-6)
    assert north_m == pytest.approx(0.9996 * _meridian_arc_m(lat_deg), abs=1e-3)
    lat, lon = p.to_latlon(east_m, north_m)
    assert lat == pytest.approx(lat_deg, abs=1e-10) and lon == pytest.approx(-69.0, abs=1e-10)


def test_arrays_and_positions_outside_the_projection():
    p = projection(UTM19)
    lat, lon = p.to_latlon(np.array([500000.0, 1e30]), np.array([0.0, 5e6]))
    assert lat[0] == pytest.approx(0.0, abs=1e-9) and math.isnan(lat[1]) and math.isnan(lon[1])


@pytest.mark.parametrize("crs, words", [
    ("EPSG:999999", ["--crs 'EPSG:999999'", "crs not found", "EPSG:32610"]),
    ("utm please", ["--crs 'utm please'", "not a coordinate reference system"]),
    ("EPSG:4978", ["--crs 'EPSG:4978'", "Geocentric CRS"]),
    ("EPSG:4979", ["Geographic 3D CRS"]),
])
def test_unknown_or_unusable_crs_is_one_clear_line(crs, words):
    with pytest.raises(ConfigError) as err:
        projection(crs)
    assert all(w in str(err.value) for w in words) and "\n" not in str(err.value)


# -- the reader and the writer ----------------------------------------------------------------

def test_writer_puts_easting_and_northing_and_navunits_0(pair):
    # the two files have the same packets at the same offsets: compare every ping's position
    ll, utm = (p.read_bytes() for p in pair)
    assert XTFFileHeader.create_from_buffer(utm[:1024]).NavUnits == 0
    assert XTFFileHeader.create_from_buffer(ll[:1024]).NavUnits == 3
    assert len(ll) == len(utm)
    proj, off, n = projection(UTM19), 1024, 0
    while off < len(ll):
        a, b = (XTFPingHeader.from_buffer_copy(d[off:off + 256]) for d in (ll, utm))
        if a.SensorXcoordinate == 0.0 and a.SensorYcoordinate == 0.0:
            assert b.SensorXcoordinate == 0.0 and b.SensorYcoordinate == 0.0  # no fix stays no fix
        else:
            east_m, north_m = proj.from_latlon(a.SensorYcoordinate, a.SensorXcoordinate)
            assert (b.SensorXcoordinate, b.SensorYcoordinate) == pytest.approx((east_m, north_m), abs=1e-6)
            assert (b.ShipXcoordinate, b.ShipYcoordinate) == (b.SensorXcoordinate, b.SensorYcoordinate)
            assert 166000 < b.SensorXcoordinate < 834000  # UTM eastings, not degrees
            n += 1
        off += a.NumBytesThisRecord
    assert n >= 400


def test_projected_file_reads_as_the_latlon_one(pair):
    latlon, utm = pair
    a, b = _tiles(latlon), _tiles(utm, crs=UTM19)
    assert [(t.side, t.seq, t.rows) for t in a] == [(t.side, t.seq, t.rows) for t in b]
    assert sum(t.nav is not None for t in b) >= 4
    for x, y in zip(a, b):
        assert (x.nav is None) == (y.nav is None)
        if x.nav is not None:
            np.testing.assert_allclose(y.nav.lat_deg, x.nav.lat_deg, atol=1e-9, rtol=0)
            np.testing.assert_allclose(y.nav.lon_deg, x.nav.lon_deg, atol=1e-9, rtol=0)
            np.testing.assert_array_equal(y.nav.heading_deg, x.nav.heading_deg)
            assert y.dx_m == pytest.approx(x.dx_m, rel=1e-9)
        np.testing.assert_array_equal(y.pixels, x.pixels)
    reader = XtfReader(utm, crs=UTM19)
    list(reader)
    assert "projected metres in EPSG:32619 (WGS 84 / UTM zone 19N)" in reader.stats.summary()


def test_projected_file_without_crs_fails_at_once_naming_the_option(pair):
    with pytest.raises(LogFormatError) as err:
        XtfReader(pair[1])  # the header is read at construction: nothing is iterated
    msg = str(err.value)
    assert msg.startswith(f"{pair[1]}: positions are projected metres (XTF NavUnits 0)")
    assert "--crs" in msg and "EPSG:32610" in msg and "\n" not in msg


def test_latlon_file_ignores_a_crs_with_one_warning(pair, caplog):
    with caplog.at_level(logging.WARNING):
        b = _tiles(pair[0], crs=UTM19)
    assert [r.getMessage() for r in caplog.records if "ignored" in r.getMessage()] == [
        f"{pair[0]}: positions are degrees (XTF NavUnits 3): --crs {UTM19} ignored"]
    a = _tiles(pair[0])
    assert all(np.array_equal(x.nav.lat_deg, y.nav.lat_deg) for x, y in zip(a, b) if x.nav is not None)


def test_navunits_outside_the_specification_need_a_crs(pair, tmp_path):
    data = bytearray(pair[0].read_bytes())
    struct.pack_into("<H", data, NAV_UNITS_AT, 2)  # the XTF specification defines 0 and 3 only
    odd = tmp_path / "odd.xtf"
    odd.write_bytes(bytes(data))
    with pytest.raises(LogFormatError, match=r"NavUnits 2 is not an XTF value .* --crs EPSG:4326 for degrees"):
        XtfReader(odd)
    # the user says what they are: degrees
    a, b = _tiles(pair[0]), _tiles(odd, crs="EPSG:4326")
    assert all(np.allclose(x.nav.lat_deg, y.nav.lat_deg, atol=1e-12) for x, y in zip(a, b) if x.nav is not None)


def test_writer_refuses_a_geographic_crs(tmp_path):
    with pytest.raises(ConfigError, match="geographic"):
        XtfWriter(tmp_path / "x.xtf", crs="EPSG:4326")
    assert not (tmp_path / "x.xtf").exists()


def test_calibration_sources_take_the_crs(pair):
    settings = Settings()
    with pytest.raises(LogFormatError, match="--crs"):
        images_from_paths([pair[1]], settings=settings, max_images=1, pixel_m=None, range0_m=None)
    (img,) = images_from_paths([pair[1]], settings=settings, max_images=1, pixel_m=None, range0_m=None, crs=UTM19)
    (ref,) = images_from_paths([pair[0]], settings=settings, max_images=1, pixel_m=None, range0_m=None)
    np.testing.assert_array_equal(img.pixels, ref.pixels)


# -- the commands -----------------------------------------------------------------------------

def test_replay_with_crs_gives_the_contacts_of_the_latlon_file(pair, tmp_path):
    latlon, utm = pair
    common = ["--online-calibration", "off", "--publish", "none", "--workers", "0", "--quiet"]
    r1 = run_cli("replay", latlon, *common, "--contacts-out", tmp_path / "a.jsonl")
    r2 = run_cli("replay", utm, "--crs", UTM19, *common, "--contacts-out", tmp_path / "b.jsonl")
    assert r1.returncode == 0 and r2.returncode == 0, r1.stderr + r2.stderr
    a = [json.loads(x) for x in (tmp_path / "a.jsonl").read_text().splitlines()]
    b = [json.loads(x) for x in (tmp_path / "b.jsonl").read_text().splitlines()]
    assert a and len(a) == len(b)
    for x, y in zip(a, b):
        assert {k for k in x if isinstance(x[k], (str, int, list)) and x[k] != y[k]} == set()
        assert y["east_m"] == pytest.approx(x["east_m"], abs=1e-6)
        assert y["north_m"] == pytest.approx(x["north_m"], abs=1e-6)
        assert y["lat_deg"] == pytest.approx(x["lat_deg"], abs=1e-10)
        assert y["bel"] == pytest.approx(x["bel"], abs=1e-9)


def test_replay_without_crs_fails_in_one_line_and_writes_nothing(pair, tmp_path):
    outs = [tmp_path / "c.jsonl", tmp_path / "s.json", tmp_path / "d.jsonl"]
    r = run_cli("replay", pair[1], "--online-calibration", "off", "--publish", "none", "--workers", "0",
             "--contacts-out", outs[0], "--summary", outs[1], "--detections-out", outs[2],
             "--state-dir", tmp_path / "state", timeout=120)
    assert r.returncode == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    assert lines[0] == (f"atr-node replay: error: {pair[1]}: positions are projected metres (XTF NavUnits 0): "
                        "give their CRS with --crs (or the recording.crs key), e.g. --crs EPSG:32610")
    assert not any(p.exists() for p in outs) and not any((tmp_path / "state").glob("*"))


def test_crs_from_the_config_and_the_command_line_wins(pair, tmp_path, capsys):
    good = tmp_path / "good.toml"
    good.write_text(f'[recording]\ncrs = "{UTM19}"\n')
    bad = tmp_path / "bad.toml"
    bad.write_text('[recording]\ncrs = "EPSG:999999"\n')
    common = ["--online-calibration", "off", "--publish", "none", "--workers", "0", "--quiet"]
    assert main(["replay", str(pair[1]), "--config", str(good), *common]) == 0
    capsys.readouterr()
    assert main(["replay", str(pair[1]), "--config", str(bad), *common]) == 1
    err = capsys.readouterr().err
    assert "recording.crs 'EPSG:999999': not a coordinate reference system" in err
    assert main(["replay", str(pair[1]), "--config", str(bad), "--crs", UTM19, *common]) == 0


def test_convert_both_ways_with_crs(pair, tmp_path, capsys):
    log = tmp_path / "u.atrlog"
    assert main(["convert", str(pair[1]), str(log)]) == 1
    err = capsys.readouterr().err
    assert "--crs" in err and len(err.strip().splitlines()) == 1 and not log.exists()
    assert main(["convert", str(pair[1]), str(log), "--crs", UTM19]) == 0
    assert "positions: projected metres in EPSG:32619" in capsys.readouterr().out
    back = tmp_path / "back.xtf"
    assert main(["convert", str(log), str(back), "--crs", UTM19]) == 0
    assert XTFFileHeader.create_from_buffer(back.read_bytes()[:1024]).NavUnits == 0
    a, b = _tiles(pair[0]), _tiles(back, crs=UTM19)
    assert all(np.allclose(x.nav.lon_deg, y.nav.lon_deg, atol=1e-9, rtol=0) for x, y in zip(a, b)
               if x.nav is not None)
    assert main(["convert", str(pair[1]), str(tmp_path / "v.atrlog"), "--crs", "nonsense"]) == 1
    assert "--crs 'nonsense': not a coordinate reference system" in capsys.readouterr().err
    assert not (tmp_path / "v.atrlog").exists()


def test_calibrate_and_batch_fail_at_once_without_crs(pair, tmp_path):
    r = run_cli("calibrate", "--input", pair[1], "--out", tmp_path / "m.json", "--no-plots", "--no-progress",
             timeout=120)
    assert r.returncode == 1 and "--crs" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = run_cli("batch", pair[1], "--scheduler", "serial", "--quiet", "--contacts-out", tmp_path / "c.jsonl",
             timeout=120)
    assert r.returncode == 1 and "--crs" in r.stderr and "attempt" not in r.stderr
    assert not (tmp_path / "m.json").exists() and not (tmp_path / "c.jsonl").exists()


def test_evaluate_log_takes_the_crs(pair, tmp_path):
    """evaluate --log reads XTF, so it takes --crs (ICD v1.1 section 6): without it a projected
    file fails in one line naming the option, before --out exists; with it the run scores."""
    truth = tmp_path / "truth.csv"
    truth.write_text("lat_deg,lon_deg,shape\n48.0,-68.0,cylinder\n")
    r = run_cli("evaluate", "--log", pair[1], "--truth", truth, "--out", tmp_path / "ev", "--online-calibration", "off",
             timeout=300)
    assert r.returncode == 1 and "--crs" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "ev").exists()
    r = run_cli("evaluate", "--log", pair[1], "--truth", truth, "--out", tmp_path / "ev", "--online-calibration", "off",
             "--crs", UTM19, timeout=300)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "ev" / "contacts.jsonl").is_file()


def test_batch_with_crs_gives_the_contacts_of_the_latlon_file(pair, tmp_path):
    r1 = run_cli("batch", pair[0], "--scheduler", "serial", "--quiet", "--contacts-out", tmp_path / "a.jsonl")
    r2 = run_cli("batch", pair[1], "--crs", UTM19, "--scheduler", "serial", "--quiet",
              "--contacts-out", tmp_path / "b.jsonl", "--summary", tmp_path / "s.json")
    assert r1.returncode == 0 and r2.returncode == 0, r1.stderr + r2.stderr
    a = [json.loads(x) for x in (tmp_path / "a.jsonl").read_text().splitlines()]
    b = [json.loads(x) for x in (tmp_path / "b.jsonl").read_text().splitlines()]
    assert a and [c["id"] for c in a] == [c["id"] for c in b]
    assert all(y["east_m"] == pytest.approx(x["east_m"], abs=1e-6) for x, y in zip(a, b))
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["tiles_dropped"] == sum(summary["drop_reasons"].values())
