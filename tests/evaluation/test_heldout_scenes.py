"""Held-out scene generator (issue 17, item 1): files, determinism, geometry, what the tiles
show, K speckle, and its independence from the node's own simulator.

Scenes are small (2 legs of 60 m) and read back through the project's readers; the target,
shadow and one-leg checks locate objects from the truth CSVs and the tiles' own nav only.
"""

from __future__ import annotations

import ast
import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

import atr_node.evaluation.heldout as heldout
from atr_node.evaluation.heldout import SEABEDS, generate_scene, k_intensity
from atr_node.evaluation.scoring import read_truth
from atr_node.geo import MissionFrame
from atr_node.io.atrlog import read_atrlog
from atr_node.records.tile import Tile

SMALL = dict(legs=2, leg_length_m=60.0)
BRIGHT, DARK = 4.0, 0.2
"""A 5x5 mean over the seabed's mean: above BRIGHT is an echo, below DARK a shadow."""
FILES = ("mission.atrlog", "truth.csv", "clutter.csv", "one_leg.csv", "scene.json")


def _textures() -> Path:
    d = heldout.default_textures_dir()
    if not d.is_dir():
        pytest.skip(f"SAS textures not found at {d} (set ATR_SAS_TEXTURES)")
    return d


@pytest.fixture(scope="module")
def sand(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sand")
    generate_scene(out, seabed="sand", seed=7, **SMALL)
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _tiles(out: Path) -> list[Tile]:
    return [Tile.from_map(r.msg) for r in read_atrlog(out / "mission.atrlog") if r.link == "sonar"]


def _locate(tile: Tile, frame: MissionFrame, lat: float, lon: float) -> tuple[float, float] | None:
    """(row, col) of a world point in a ground-range tile, from the tile's nav alone."""
    e, n = frame.to_frame(tile.nav.lat_deg, tile.nav.lon_deg)
    oe, on = frame.to_frame(lat, lon)
    h = np.radians(tile.nav.heading_deg)
    ae, an = np.sin(h), np.cos(h)
    se, sn = (np.cos(h), -np.sin(h)) if tile.side == "stbd" else (-np.cos(h), np.sin(h))
    along = (oe - e) * ae + (on - n) * an
    i = int(np.argmin(np.abs(along)))
    if abs(along[i]) > tile.dx_m:
        return None
    rng_m = float((oe - e[i]) * se[i] + (on - n[i]) * sn[i])
    return i, (rng_m - tile.range0_m) / tile.dr_m


def _sightings(out: Path, csv_name: str, min_range_m: float = 10.0, max_range_m: float = 50.0):
    """(object row, tile, row, col) for every tile side imaging an object at min-max range,
    away from the tile's first and last 15 pings."""
    scene = json.loads((out / "scene.json").read_text())
    frame = MissionFrame.from_dict(scene["frame"])
    tiles = _tiles(out)
    for obj in _rows(out / csv_name):
        for t in tiles:
            at = _locate(t, frame, float(obj["lat_deg"]), float(obj["lon_deg"]))
            if at is None:
                continue
            i, c = at
            if 15 <= i < t.rows - 15 and min_range_m / t.dr_m <= c <= max_range_m / t.dr_m:
                yield obj, t, int(i), int(round(c))


def _echo_and_shadow(t: Tile, i: int, c: int, size_m: float) -> tuple[float, float]:
    """(brightest 5x5 mean near the point, darkest 5x5 mean behind it in range), both over
    the seabed level: the mean intensity of the same rows 4-9 m nearer the sonar."""
    px = np.nan_to_num(t.pixels, nan=0.0).astype(np.float64)
    half_rows = int(round((size_m / 2 + 1.0) / t.dx_m))
    r0, r1 = max(i - half_rows, 0), min(i + half_rows + 1, t.rows)
    seabed = float(np.nanmean(t.pixels[r0:r1, c - 90:c - 40]))
    box = ndimage.uniform_filter(px, 5)
    bright = box[r0:r1, c - 25:c + 25]
    jb = int(np.unravel_index(np.argmax(bright), bright.shape)[1]) + c - 25
    dark = box[r0:r1, jb + 1:c + int(size_m / t.dr_m) + 40]
    return float(bright.max()) / seabed, float(dark.min()) / seabed


# ----------------------------------------------------------------------------------------


def test_files_written_and_readable(sand):
    for name in FILES:
        assert (sand / name).is_file(), name
    scene = json.loads((sand / "scene.json").read_text())
    assert scene["generator_version"] == heldout.GENERATOR_VERSION and scene["seed"] == 7
    assert len(scene["per_leg"]) == 2
    for leg in scene["per_leg"]:
        off = math.hypot(leg["nav_offset_east_m"], leg["nav_offset_north_m"])
        assert 0.4 <= off <= 0.6, leg
    assert len(read_truth(sand / "truth.csv")) == 16
    rocks = _rows(sand / "clutter.csv")
    assert 40 <= len(rocks) <= 110 and sum(r["target_like"] == "1" for r in rocks) >= 10
    one = _rows(sand / "one_leg.csv")
    assert 4 <= len(one) <= 6
    assert list(one[0])[:5] == ["lat_deg", "lon_deg", "shape", "shown_on_leg", "covered_by_legs"]

    records = list(read_atrlog(sand / "mission.atrlog", strict=True))
    times = [r.t for r in records]
    assert times == sorted(times) and all(r.link == "sonar" for r in records)
    tiles = [Tile.from_map(r.msg) for r in records]
    assert len(tiles) == scene["counts"]["tiles"]
    for side in ("port", "stbd"):
        assert [t.seq for t in tiles if t.side == side] == list(range(len(tiles) // 2))
    dropped = 0
    for t in tiles:
        assert not t.slant and t.kind == "intensity" and t.range0_m == 0.0 and t.dr_m == t.dx_m == 0.1
        assert t.rows <= 256 and t.ranges_m[-1] == pytest.approx(60.0)
        assert np.isnan(t.pixels[:, t.ranges_m < 5.0]).all()  # the nadir gap
        assert np.all(np.abs(t.nav.altitude_m - 8.0) <= 0.3 + 1e-9)
        full = np.isnan(t.pixels[:, t.ranges_m >= 5.0]).all(axis=1)
        dropped += int(full.sum())
        assert np.isfinite(t.pixels[~full][:, t.ranges_m >= 5.0]).all()
    assert dropped >= 2 * 3 * 2  # a few dropped pings per leg, on both sides


def test_same_seed_same_bytes_other_seed_other_scene(sand, tmp_path):
    generate_scene(tmp_path / "a", seabed="sand", seed=7, **SMALL)
    for name in FILES:
        assert (tmp_path / "a" / name).read_bytes() == (sand / name).read_bytes(), name
    generate_scene(tmp_path / "b", seabed="sand", seed=8, **SMALL)
    assert (tmp_path / "b" / "truth.csv").read_bytes() != (sand / "truth.csv").read_bytes()


def test_truth_lies_in_the_imaged_swath_and_objects_keep_apart(tmp_path):
    out = tmp_path / "s"
    generate_scene(out, seabed="ripples", seed=3, legs=3, leg_length_m=80.0)
    scene = json.loads((out / "scene.json").read_text())
    frame = MissionFrame.from_dict(scene["frame"])
    legs = scene["per_leg"]

    def leg_coords(leg, e, n):
        h = math.radians(leg["heading_deg"])
        de, dn = e - leg["start_east_m"], n - leg["start_north_m"]
        return de * math.sin(h) + dn * math.cos(h), de * math.cos(h) - dn * math.sin(h)

    everything = []
    for name in ("truth.csv", "clutter.csv", "one_leg.csv"):
        for row in _rows(out / name):
            e, n = frame.to_frame(float(row["lat_deg"]), float(row["lon_deg"]))
            assert float(e) == pytest.approx(float(row["east_m"]), abs=2e-3)
            assert float(n) == pytest.approx(float(row["north_m"]), abs=2e-3)
            seen = []
            for leg in legs:
                a, c = leg_coords(leg, float(e), float(n))
                if 0 <= a <= (leg["pings"] - 1) * 0.1 and 5.0 <= abs(c) <= 60.0:
                    seen.append(str(leg["leg"]))
            assert row["seen_by_legs"] == ";".join(seen) and int(row["looks"]) == len(seen), row
            everything.append((float(e), float(n), row, name))
    targets = [x for x in everything if x[3] == "truth.csv"]
    assert all(int(r["looks"]) >= 1 for _, _, r, _ in targets)
    assert sum(2 <= int(r["looks"]) <= 3 for _, _, r, _ in targets) >= 10
    seen_once_in_gap = [x for x in targets if int(x[2]["looks"]) == 1
                        and any(abs(leg_coords(leg, x[0], x[1])[1]) < 5.0 for leg in legs)]
    assert len(seen_once_in_gap) >= 2
    for _, _, r, _ in (x for x in everything if x[3] == "one_leg.csv"):
        assert r["shown_on_leg"] in r["seen_by_legs"].split(";") and r["covered_by_legs"]
        assert r["shown_on_leg"] not in r["covered_by_legs"].split(";")
    xy = np.array([(e, n) for e, n, _, _ in everything])
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    assert d.min() >= 3.0


def test_a_target_shows_an_echo_and_a_shadow_behind_it(sand):
    checked = 0
    for obj, t, i, c in _sightings(sand, "truth.csv"):
        h, rng_m, size = float(obj["height_m"]), c * t.dr_m, float(obj["size_m"])
        if h * rng_m / (8.3 - h) < 0.8:  # too low to cast a shadow of 0.8 m
            continue
        bright, dark = _echo_and_shadow(t, i, c, size)
        assert bright > BRIGHT, (obj["shape"], t.ident, i, c, bright)
        assert dark < DARK, (obj["shape"], t.ident, i, c, dark)
        checked += 1
    assert checked >= 10
    # The same statistics on bare seabed (nothing within 8 m) do not pass: the check can fail.
    scene = json.loads((sand / "scene.json").read_text())
    frame = MissionFrame.from_dict(scene["frame"])
    objs = np.array([frame.to_frame(float(r["lat_deg"]), float(r["lon_deg"]))
                     for n in ("truth.csv", "clutter.csv", "one_leg.csv") for r in _rows(sand / n)], dtype=float)
    bare = []
    for t in _tiles(sand):
        e, n = frame.to_frame(t.nav.lat_deg, t.nav.lon_deg)
        sgn = 1.0 if t.side == "stbd" else -1.0
        h = np.radians(t.nav.heading_deg)
        for c in range(150, 500, 25):
            for i in range(20, t.rows - 20, 20):
                pe, pn = e[i] + sgn * c * t.dr_m * np.cos(h[i]), n[i] - sgn * c * t.dr_m * np.sin(h[i])
                clear = np.hypot(objs[:, 0] - pe, objs[:, 1] - pn).min() > 8.0
                if clear and np.isfinite(t.pixels[i - 15:i + 16, 50:]).all():
                    bare.append(_echo_and_shadow(t, i, c, 1.0))
    bare = np.array(bare)
    assert len(bare) >= 50
    assert not np.any((bare[:, 0] > BRIGHT) & (bare[:, 1] < DARK))
    assert np.mean(bare[:, 0] > BRIGHT) < 0.05 and np.mean(bare[:, 1] < DARK) < 0.05


def test_one_leg_object_shows_on_its_leg_only(tmp_path):
    out = tmp_path / "s"
    generate_scene(out, seabed="sand", seed=11, legs=3, leg_length_m=80.0)
    shown = covered = 0
    for obj, t, i, c in _sightings(out, "one_leg.csv", 6.0, 57.0):
        bright, dark = _echo_and_shadow(t, i, c, float(obj["size_m"]))
        if str(t.leg) == obj["shown_on_leg"]:
            assert bright > BRIGHT and dark < DARK, (t.ident, bright, dark)
            shown += 1
        else:
            assert str(t.leg) in obj["covered_by_legs"].split(";")
            assert not (bright > BRIGHT and dark < DARK), (t.ident, obj, bright, dark)
            assert bright < BRIGHT, (t.ident, obj, bright, dark)  # no echo: nothing there
            covered += 1
    assert shown >= 3 and covered >= 3


def test_k_intensity_has_the_k_distribution_second_moment():
    rng = np.random.default_rng(5)
    for nu in (2.0, 5.0, 20.0):
        i = k_intensity(np.full(400_000, 3.0), nu, rng)
        assert i.mean() == pytest.approx(3.0, rel=0.02)
        m2 = np.mean(i * i) / i.mean() ** 2
        assert m2 == pytest.approx(2 * (1 + 1 / nu), rel=0.03), nu


def test_correlated_k_intensity_keeps_the_k_marginal():
    """The clumpy variant's texture (Gaussian copula) and speckle (smoothed complex Gaussian)
    keep the K distribution's mean and second moment, 2 (1 + 1/nu) [1]."""
    rng = np.random.default_rng(11)
    for nu in (2.0, 8.0):
        i = heldout.k_intensity_correlated(np.full((800, 800), 3.0), nu, rng, texture_px=4.0, speckle_px=0.8)
        assert i.mean() == pytest.approx(3.0, rel=0.03)
        assert np.mean(i * i) / i.mean() ** 2 == pytest.approx(2 * (1 + 1 / nu), rel=0.06), nu


def _lag1(x: np.ndarray) -> float:
    x = (x - x.mean()) / x.std()
    return float(np.mean(x[:, 1:] * x[:, :-1]))


def test_oversampled_speckle_has_the_correlation_of_its_smoothing():
    """|c|^2 of complex white noise smoothed by a Gaussian of s pixels: the field's correlation
    at lag d is exp(-d^2 / (4 s^2)), the intensity's its square (circular Gaussian field):
    exp(-d^2 / (2 s^2)), 0.458 at d = 1, s = 0.8. The base speckle is uncorrelated."""
    rng = np.random.default_rng(12)
    mean = np.ones((1000, 1000))
    sp = heldout.k_intensity_correlated(mean, 1e7, rng, texture_px=0.0, speckle_px=0.8)  # nu -> inf: G = 1
    assert _lag1(sp) == pytest.approx(math.exp(-1.0 / (2 * 0.8 ** 2)), abs=0.02)
    assert abs(_lag1(k_intensity(mean, 1e7, rng))) < 0.01


def test_variants_change_the_survey_and_leave_the_base_scene_alone(sand, tmp_path):
    assert "variant" not in json.loads((sand / "scene.json").read_text())
    fine = generate_scene(tmp_path / "fine", seabed="sand", seed=7, variant="fine", **SMALL)
    scene = json.loads(fine.scene_json.read_text())
    assert scene["variant"]["name"] == "fine" and scene["dr_m"] == 0.05 and scene["tile_pings"] == 512
    tiles = _tiles(tmp_path / "fine")
    assert {(t.dr_m, t.dx_m) for t in tiles} == {(0.05, 0.05)} and max(t.rows for t in tiles) == 512
    assert tiles[0].cols == 1201  # 0-60 m
    base_truth, fine_truth = _rows(sand / "truth.csv"), _rows(tmp_path / "fine" / "truth.csv")
    assert [r["shape"] for r in fine_truth] == [r["shape"] for r in base_truth]
    high = generate_scene(tmp_path / "high", seabed="sand", seed=7, variant="high", **SMALL)
    tiles = _tiles(tmp_path / "high")
    assert tiles[0].cols == 1001  # 0-100 m at 0.1 m
    alt = np.concatenate([t.nav.altitude_m for t in tiles])
    assert abs(alt.mean() - 15.0) < 0.3 and alt.max() - alt.min() <= 2 * heldout.SWELL_M + 1e-6
    for r in _rows(tmp_path / "high" / "truth.csv"):
        assert r["seen_by_legs"]  # every target inside some leg's 5-100 m swath
    assert high.targets == 16
    aniso = generate_scene(tmp_path / "aniso", seabed="sand", seed=7, variant="aniso", **SMALL)
    tiles = _tiles(tmp_path / "aniso")
    assert {(t.dr_m, t.dx_m) for t in tiles} == {(0.05, 0.2)} and max(t.rows for t in tiles) == 128
    assert tiles[0].cols == 1201 and aniso.targets == 16
    spiky = generate_scene(tmp_path / "spiky", seabed="sand", seed=7, variant="spiky", **SMALL)
    assert 0.7 <= spiky.nu <= 1.5
    assert json.loads(spiky.scene_json.read_text())["variant"]["nu_range"] == [0.7, 1.5]
    nav2 = generate_scene(tmp_path / "nav2", seabed="sand", seed=7, variant="nav2", **SMALL)
    base_legs = json.loads((sand / "scene.json").read_text())["per_leg"]
    for a, b in zip(base_legs, json.loads(nav2.scene_json.read_text())["per_leg"]):  # the same draws, 4 x
        for k in ("nav_offset_east_m", "nav_offset_north_m", "nav_drift_east_m_per_100m", "nav_wobble_m"):
            assert b[k] == pytest.approx(4 * a[k], abs=4e-6), k
        assert b["nav_wobble_wavelength_m"] == a["nav_wobble_wavelength_m"]
    with pytest.raises(ValueError, match="variant must be one of"):
        generate_scene(tmp_path / "x", seabed="sand", seed=7, variant="blurry", **SMALL)


def test_the_byte_variant_is_the_base_scene_as_an_8_bit_recorder_stores_it(sand, tmp_path):
    """An 8-bit recorder: the same scene (same draws) in uint8 amplitude, round(255 sqrt(I / F)),
    clipped at 255, with the full scale F the scene states; dropped pings and the nadir gap stay
    no-data. Checked against the base scene's float intensity, pixel by pixel."""
    b = generate_scene(tmp_path / "byte", seabed="sand", seed=7, variant="byte", **SMALL)
    rec = json.loads(b.scene_json.read_text())["recorder"]
    assert 4.0 <= rec["headroom_db"] <= 10.0
    fs = rec["full_scale_intensity"]
    assert fs == pytest.approx(heldout.LEVEL * 10.0 ** (rec["headroom_db"] / 10.0), rel=1e-6)
    base, byte = _tiles(sand), _tiles(tmp_path / "byte")
    assert len(base) == len(byte)
    clipped = total = 0
    for t0, t1 in zip(base, byte):
        assert (t1.kind, t1.wire_dtype, t0.kind, t0.wire_dtype) == ("amplitude", "uint8", "intensity", "float32")
        np.testing.assert_array_equal(np.isnan(t0.pixels), np.isnan(t1.pixels))
        ok = np.isfinite(t0.pixels)
        want = np.clip(np.rint(255.0 * np.sqrt(t0.pixels[ok].astype(np.float64) / fs)), 1.0, 255.0)
        np.testing.assert_array_equal(t1.pixels[ok], want)
        clipped += int(np.count_nonzero(t1.pixels[ok] == 255.0))
        total += int(ok.sum())
    # a recorder set 4-10 dB over the seabed does clip: echoes and the speckle's brightest,
    # and the node reads 255 off the samples as the clip level
    assert 1e-3 < clipped / total < 0.2
    assert any(t.clip_level == 255.0 for t in byte)
    assert _rows(tmp_path / "byte" / "truth.csv") == _rows(sand / "truth.csv")


def test_a_flat_patch_of_a_scene_is_k_distributed(tmp_path):
    out = tmp_path / "s"
    sc = generate_scene(out, seabed="sand", seed=4, legs=2, leg_length_m=120.0)
    assert sc.nu < 6.0  # a small nu, so K is told apart from Rayleigh (m2 = 2) by far
    scene = json.loads((out / "scene.json").read_text())
    frame = MissionFrame.from_dict(scene["frame"])
    objs = [frame.to_frame(float(r["lat_deg"]), float(r["lon_deg"]))
            for n in ("truth.csv", "clutter.csv", "one_leg.csv") for r in _rows(out / n)]
    oe, on = np.array([o[0] for o in objs], dtype=float), np.array([o[1] for o in objs], dtype=float)
    m2s = []
    for t in _tiles(out):
        cols = (t.ranges_m >= 12.0) & (t.ranges_m <= 20.0)
        e, n = frame.to_frame(t.nav.lat_deg, t.nav.lon_deg)
        # The patch: pings whose 12-20 m band has no object within 10 m of its middle.
        h = np.radians(t.nav.heading_deg)
        s = (1.0 if t.side == "stbd" else -1.0)
        mid_e, mid_n = e + s * 16.0 * np.cos(h), n - s * 16.0 * np.sin(h)
        clear = np.min(np.hypot(oe[None, :] - mid_e[:, None], on[None, :] - mid_n[:, None]), axis=1) > 10.0
        p = t.pixels[clear][:, cols].astype(np.float64)
        p = p[np.isfinite(p).all(axis=1)]
        if p.shape[0] >= 50:
            p = p / p.mean(axis=0)  # the mean varies with range (gain): normalise per column
            m2s.append((np.mean(p * p), p.size))
    assert sum(n for _, n in m2s) > 50_000
    m2 = sum(m * n for m, n in m2s) / sum(n for _, n in m2s)
    assert m2 == pytest.approx(2 * (1 + 1 / sc.nu), rel=0.08)


def test_sassed_seabed_uses_the_textures_and_names_a_missing_folder(tmp_path, monkeypatch):
    tex = _textures()
    sc = generate_scene(tmp_path / "s", seabed="sassed", seed=1, textures_dir=tex, **SMALL)
    scene = json.loads(sc.scene_json.read_text())
    assert (tex / scene["seabed"]["texture"]).is_file()
    missing = tmp_path / "no-textures"
    with pytest.raises(FileNotFoundError, match=str(missing)):
        generate_scene(tmp_path / "x", seabed="sassed", seed=1, textures_dir=missing, **SMALL)
    monkeypatch.setenv(heldout.TEXTURES_ENV, str(missing))
    with pytest.raises(FileNotFoundError, match=str(missing)):
        generate_scene(tmp_path / "y", seabed="sassed", seed=1, **SMALL)


def test_command_line(tmp_path):
    py = [sys.executable, "-m", "atr_node.evaluation.heldout"]
    r = subprocess.run(py + ["--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "--seabed" in r.stdout
    r = subprocess.run(py + [str(tmp_path / "a"), "--seabed", "mud", "--seed", "1"], capture_output=True, text=True)
    assert r.returncode == 2 and "mud" in r.stderr
    r = subprocess.run(py + [str(tmp_path / "a"), "--seabed", "sand", "--seed", "1", "--legs", "1"],
                       capture_output=True, text=True)
    assert r.returncode == 1 and r.stderr.strip().count("\n") == 0 and "legs" in r.stderr
    r = subprocess.run(py + [str(tmp_path / "a"), "--seabed", "sassed", "--seed", "1", "--textures",
                             str(tmp_path / "none")], capture_output=True, text=True)
    assert r.returncode == 1 and str(tmp_path / "none") in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run(py + [str(tmp_path / "a"), "--seabed", "sand", "--seed", "1", "--legs", "2",
                             "--leg-length-m", "40", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert all((tmp_path / "a" / f).is_file() for f in FILES)


def test_independent_of_the_node_s_simulator_and_algorithms():
    src = Path(heldout.__file__)
    tree = ast.parse(src.read_text())
    forbidden = ("atr_node.simulation", "atr_node.detectors", "atr_node.calibration", "atr_node.fusion")
    package = "atr_node.evaluation"
    imported = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package.split(".")[: len(package.split(".")) - node.level + 1] if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            imported += [mod] + [f"{mod}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) in (
                "__import__", "import_module"):
            imported.append("<dynamic import>")
    assert imported, "the parser found no import at all"
    bad = [m for m in imported if m == "<dynamic import>" or any(m == f or m.startswith(f + ".") for f in forbidden)]
    assert not bad, bad
    assert "atr_node.records.tile" in imported and "atr_node.io.atrlog" in imported
    assert set(SEABEDS) == {"sand", "ripples", "sassed"}


def test_an_interrupted_scene_leaves_the_folder_as_it_was(sand, tmp_path):
    """Files are written under hidden temporary names beside their final ones and renamed when
    the scene is done: a run stopped midway (here by its progress callback, as Ctrl-C would)
    leaves no file of it, and an earlier scene there stays whole."""
    import shutil

    out = tmp_path / "scene"
    shutil.copytree(sand, out)  # an earlier scene in the folder
    before = {f: (out / f).read_bytes() for f in FILES}

    def stop(done, total):
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate_scene(out, seabed="sand", seed=4, progress=stop, **SMALL)
    assert {f: (out / f).read_bytes() for f in FILES} == before
    assert sorted(p.name for p in out.iterdir()) == sorted(FILES)  # no partial folder left in it
    with pytest.raises(KeyboardInterrupt):
        generate_scene(tmp_path / "new", seabed="sand", seed=4, progress=stop, **SMALL)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]  # the folder it made is gone again
    # a file where the folder should be: refused before any rendering
    (tmp_path / "file").write_text("x")
    calls = []
    with pytest.raises(ValueError, match="not a folder"):
        generate_scene(tmp_path / "file", seabed="sand", seed=4, progress=lambda *a: calls.append(a), **SMALL)
    assert calls == [] and (tmp_path / "file").read_text() == "x"
