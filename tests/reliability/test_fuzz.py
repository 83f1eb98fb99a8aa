"""Fuzzing of every parser that sees outside data (issue 10): Hypothesis properties here with a
modest number of examples, the mutation fuzzer ``tools/fuzz.py`` on a short run, and
the inputs it found that crashed a parser before the fixes, kept as regressions."""

from __future__ import annotations

import json
import math

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from atr_node.calibration import model as model_mod
from atr_node.calibration.model import PerformanceModel
from atr_node.config import Settings, load_settings
from atr_node.errors import ConfigError, LogFormatError, ModelFileError, TileError
from atr_node.io.atrlog import AtrLogReader, AtrLogWriter, LogRecord, check_record
from atr_node.node.pipeline import Pipeline
from atr_node.records.tile import REQUIRED_KEYS, Tile
from hw.decode import NavDecoder
from hw.nmea import checksum
from hw.nmea_decoder import NmeaDecoder

from .conftest import load_tool

fz = load_tool("fuzz")
TILE_SEEDS = fz._tile_seeds()
FEW = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

scalars = st.one_of(st.none(), st.booleans(), st.integers(-2**63, 2**64 - 1), st.floats(), st.text(max_size=20),
                    st.binary(max_size=40), st.sampled_from(fz.INTERESTING[:40]))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner,
                                                                                          max_size=4), max_leaves=8)
TILE_KEYS = list(REQUIRED_KEYS) + ["nav", "sensor"]


def _clear_tile_error(exc: TileError) -> bool:
    return str(exc).startswith(exc.tile) and (exc.field is not None or "map" in str(exc))


@FEW
@given(seed=st.integers(0, len(TILE_SEEDS) - 1), changes=st.dictionaries(st.sampled_from(TILE_KEYS), values, max_size=3),
       drop=st.lists(st.sampled_from(TILE_KEYS), max_size=2))
def test_tile_from_map_gives_a_tile_or_a_tile_error_naming_tile_and_field(seed, changes, drop):
    m = dict(TILE_SEEDS[seed])
    m.update(changes)
    for k in drop:
        m.pop(k, None)
    try:
        tile = Tile.from_map(m)
    except TileError as exc:
        assert _clear_tile_error(exc), str(exc)
        return
    assert Tile.from_map(tile.to_map()).equals(tile)  # what is accepted is a faithful tile


@FEW
@given(data=st.binary(max_size=400), seed=st.integers(0, len(TILE_SEEDS) - 1), cut=st.integers(0, 10_000))
def test_tile_unpack_of_arbitrary_or_truncated_bytes(data, seed, cut):
    packed = msgpack.packb(TILE_SEEDS[seed], use_bin_type=True)
    for payload in (data, packed[:cut], packed[:cut] + data):
        try:
            Tile.unpack(payload)
        except TileError as exc:
            assert _clear_tile_error(exc), str(exc)


FIELD = st.one_of(st.sampled_from(["", "-", "nan", "inf", "1e308", "9" * 30, "12.3.4", "N", "S", "E", "W", "A", "V",
                                   "235960.00", "000000.00", "99", "00", "-0"]),
                  st.from_regex(r"\A[0-9.+-]{0,25}\Z"))


@FEW
@given(kind=st.sampled_from(["GGA", "RMC", "ZDA", "HDT", "THS", "VTG", "DPT"]), fields=st.lists(FIELD, max_size=14))
def test_nmea_decoder_counts_every_bad_sentence_and_never_raises(kind, fields):
    body = ("GP" + kind + "," + ",".join(fields)).encode()
    line = b"$" + body + b"*%02X" % checksum(body)
    d = NmeaDecoder()
    fixes = d.feed(line, 1.7e9)
    assert sum(d.counts.values()) == 1  # accepted or exactly one reason
    for f in fixes:
        for v in (f.t, f.lat_deg, f.lon_deg, f.heading_deg, f.altitude_m):
            assert v is None or math.isfinite(v)


@FEW
@given(msg=values, cid=st.integers(0, 2**29 - 1))
def test_can_records_of_any_shape_are_counted_never_raised(msg, cid):
    d = NavDecoder()
    for m in (msg, {"id": cid, "data": msg, "ext": False}, {"id": msg, "data": b"\x00" * 8, "ext": True}):
        d.feed(LogRecord(t=1.7e9, link="can", msg=m))
    assert sum(d.can.counts.values()) == 3


@FEW
@given(objs=st.lists(values, max_size=4), tail=st.binary(max_size=60))
def test_atrlog_reader_keeps_every_valid_record_before_garbage(tmp_path_factory, objs, tail):
    path = tmp_path_factory.mktemp("log") / "x.atrlog"
    good = [(1.7e9 + i, "nmea", b"$GPHDT,1.0,T*00") for i in range(3)]
    with AtrLogWriter(path) as w:
        for rec in good:
            w.write(*rec)
    with open(path, "ab") as fh:
        for o in objs:
            fh.write(msgpack.packb(fz._sanitize(o), use_bin_type=True))
        fh.write(tail)
    reader = AtrLogReader(path)
    recs = list(reader)
    assert [(r.t, r.link, r.msg) for r in recs[:3]] == good  # nothing accepted before is lost
    assert all(check_record({"t": r.t, "link": r.link, "msg": r.msg}) is None for r in recs)
    assert all(str(path) in e and "byte" in e for e in reader.errors)
    try:
        list(AtrLogReader(path, strict=True))
    except LogFormatError as exc:
        assert str(path) in str(exc) and "byte" in str(exc)


TOML_VALUES = st.sampled_from(fz.ConfigTarget.VALUES)


@FEW
@given(picks=st.lists(st.tuples(st.integers(0, 10_000), TOML_VALUES), min_size=1, max_size=3))
def test_config_with_swapped_values_loads_or_names_file_and_key(tmp_path_factory, picks):
    text = (fz.REPO / "config" / "default.toml").read_text().splitlines()
    keyed = [i for i, line in enumerate(text) if "=" in line and not line.lstrip().startswith("#")]
    for k, v in picks:
        i = keyed[k % len(keyed)]
        text[i] = text[i].split("=", 1)[0] + "= " + v
    path = tmp_path_factory.mktemp("cfg") / "fuzz.toml"
    path.write_text("\n".join(text) + "\n")
    try:
        s = load_settings(path)
    except ConfigError as exc:
        assert str(exc).startswith(f"file {path}"), str(exc)
        return
    assert isinstance(s, Settings)


@FEW
@given(seed=st.integers(0, 2**32 - 1))
def test_model_files_mutated_and_re_signed_load_usable_or_refused(tmp_path_factory, seed):
    t = fz.ModelTarget(tmp_path_factory.mktemp("model"))
    text = t.mutate(np.random.default_rng(seed), t.seeds()[0], [])
    try:
        t.run(text)  # loads and checks the loaded model is usable (confidence in (0, 1), Pd in [0, 1])
    except ModelFileError as exc:
        assert str(t.path) in str(exc)


@pytest.mark.parametrize("name", list(fz.TARGETS))
def test_mutation_fuzzer_short_run_finds_no_crash_hang_or_unclear_error(name, tmp_path):
    n = 30 if name == "pipeline" else 100
    res = fz.fuzz(name, n, seed=5, timeout_s=20.0, tmp=tmp_path)
    assert res.inputs == n
    assert res.ok, res.failures
    assert res.rejected > 0 and res.accepted > 0  # the mutations reach both outcomes


def test_fuzz_tool_cli_prints_the_table(capsys):
    assert fz.main(["--quick", "--parsers", "nmea,can", "--max-memory-gb", "0"]) == 0
    out = capsys.readouterr().out
    assert "parser" in out and "nmea" in out and "crashes + hangs + unclear: 0" in out


# -- inputs the fuzzer found, each a crash before its fix -------------------------------------

def test_regression_tile_dtype_of_unhashable_type_is_a_tile_error():
    m = dict(TILE_SEEDS[0], dtype=["float32"])
    with pytest.raises(TileError, match="dtype"):
        Tile.from_map(m)


def test_regression_atrlog_map_with_a_map_as_key_is_skipped_not_raised(tmp_path):
    path = tmp_path / "k.atrlog"
    with AtrLogWriter(path) as w:
        w.write(1.0, "nmea", b"$GPHDT,1.0,T*00")
    offset = path.stat().st_size
    with open(path, "ab") as fh:
        fh.write(b"\x81\x81\xa1a\x01\x02")  # {{"a": 1}: 2}
    reader = AtrLogReader(path)
    assert len(list(reader)) == 1 and reader.rejected == 1
    with pytest.raises(LogFormatError, match=f"byte {offset}"):
        list(AtrLogReader(path, strict=True))


def test_regression_nmea_zda_with_a_twenty_digit_year_is_counted():
    body = b"GPZDA,221320.00,14,11," + b"9" * 40 + b",,"
    d = NmeaDecoder()
    assert d.feed(b"$" + body + b"*%02X" % checksum(body), 1.7e9) == [] and d.counts["bad_field"] == 1


def test_regression_can_data_that_is_a_huge_integer_is_a_bad_frame():
    d = NavDecoder()
    assert d.feed(LogRecord(t=1.0, link="can", msg={"id": 256, "data": 2**64 - 1, "ext": False})) == []
    assert d.can.counts["bad_frame"] == 1


def test_regression_config_include_of_a_folder_is_a_config_error(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text('include = ""\n')
    with pytest.raises(ConfigError, match="cannot read"):
        load_settings(p)


def test_regression_model_file_with_nan_is_a_model_file_error(tmp_path):
    body = json.loads(model_mod.SHIPPED_MODEL.read_text()) if hasattr(model_mod.SHIPPED_MODEL, "read_text") else None
    body = body or json.loads(open(model_mod.SHIPPED_MODEL).read())
    det = next(iter(body["detectors"]))
    body["detectors"][det]["tau"] = float("nan")
    p = tmp_path / "m.json"
    p.write_text(json.dumps(body, allow_nan=True))
    with pytest.raises(ModelFileError, match="NaN or infinite"):
        PerformanceModel.load(p)


@pytest.mark.parametrize("change", [dict(slant=True, range0_m=1e300), dict(dr_m=1e-300), dict(dx_m=5e-324),
                                    dict(range0_m=1e308), dict(seq=2**64 - 1), dict(leg=2**63)])
def test_regression_tiles_with_absurd_geometry_are_rejected_not_crashing_the_node(change):
    m = dict(TILE_SEEDS[1], **change)
    with pytest.raises(TileError):
        Tile.from_map(m)
    pipe = Pipeline(Settings(), model=PerformanceModel.shipped(), workers=0)
    try:
        pipe.feed(LogRecord(t=1.7e9, link="sonar", msg=m))
        assert pipe.stats.tiles_rejected == 1
    finally:
        pipe.close()


def test_regression_same_leg_and_side_on_another_range_axis_does_not_crash_the_node():
    from atr_node.records.tile import TileNav

    rng = np.random.default_rng(3)

    def tile(seq: int, mission: str, cols: int) -> dict:
        rows = 32
        t = 1.7e9 + 1.6 * seq + 0.05 * np.arange(rows)
        nav = TileNav(lat_deg=44.1 + 1e-6 * (seq * rows + np.arange(rows)), lon_deg=np.full(rows, 9.85),
                      heading_deg=np.full(rows, 0.0), altitude_m=np.full(rows, 12.0))
        px = rng.gamma(2.0, 0.5, (rows, cols)).astype(np.float32)
        return Tile(mission=mission, leg=0, side="port", seq=seq, pixels=px, kind="intensity", range0_m=0.0,
                    dr_m=0.1, dx_m=0.1, slant=False, ping_time=t, nav=nav).to_map()

    pipe = Pipeline(Settings(), model=PerformanceModel.shipped(), workers=0)
    try:
        for seq in range(12):  # a strip of 64 columns, then the same leg and side with 80
            pipe.feed(LogRecord(t=1.7e9 + 1.6 * seq + 2, link="sonar",
                                msg=tile(seq, "a" if seq < 6 else "b", 64 if seq < 6 else 80)))
        pipe.finish()
        assert pipe.stats.tiles_in == 12 and pipe.stats.units >= 2
    finally:
        pipe.close()


def test_regression_a_slant_tile_far_out_is_not_blown_up_into_a_huge_ground_tile():
    m = dict(TILE_SEEDS[1], range0_m=65535.0)  # 16 pings x 40 slant bins at 65 km: 655 000 ground columns
    assert Tile.from_map(m).slant
    pipe = Pipeline(Settings(), model=PerformanceModel.shipped(), workers=0)
    try:
        pipe.feed(LogRecord(t=1.7e9, link="sonar", msg=m))
        pipe.finish()
        assert pipe.merger.stats.reasons.get("slant range axis too long for a ground-range tile") == 1
        assert pipe.stats.pixels == 0
    finally:
        pipe.close()


def test_config_not_utf8_is_a_config_error(tmp_path):
    """Found by atheris (tools/fuzz.py --engine atheris): a config file that is not UTF-8 raised
    UnicodeDecodeError from tomllib instead of a ConfigError naming the file."""
    path = tmp_path / "bad.toml"
    path.write_bytes(b"[detectors]\nenabled = [\"mf\", \"z\"]\n[detec\x92\x90\x00tors]\n")
    with pytest.raises(ConfigError, match="not UTF-8") as ei:
        load_settings(path)
    assert str(path) in str(ei.value)


def test_atheris_engine_smoke(tmp_path):
    """The coverage-guided engine, where atheris is installed (optional: not in the test extras)."""
    pytest.importorskip("atheris")
    import subprocess
    import sys

    import os

    scratch = tmp_path / "tmp"  # the children's working folders go here, and must be gone after
    scratch.mkdir()
    r = subprocess.run([sys.executable, str(fz.__file__), "--engine", "atheris", "--parsers", "nmea,config",
                        "--inputs", "200", "--crash-dir", str(tmp_path / "findings")], capture_output=True, text=True,
                       timeout=300, env={**os.environ, "TMPDIR": str(scratch)})
    assert r.returncode == 0, r.stdout + r.stderr[-3000:]
    assert r.stdout.count("no finding") == 2
    assert list(scratch.iterdir()) == []  # libFuzzer ends each child with exit(): its folder was left behind
