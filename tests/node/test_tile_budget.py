"""The node's memory budget for one tile (issue 21 item 4): ``node.max_tile_pixels``.

Detection and fusion take about 225 MiB plus 80 B per pixel of a tile; an 8192 x 8192 uint8
tile (within the wire format's 2^28) peaked at 4.8 GB. Beyond the limit a tile is refused
before its pixels are converted, with one line naming it, and counted.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from atr_node.config import NodeSettings
from atr_node.errors import AtrError, TileError
from atr_node.io.atrlog import AtrLogWriter
from atr_node.records.tile import Tile, TileNav

REPO = Path(__file__).resolve().parents[2]


def _tile(rows: int, cols: int, *, slant: bool = False) -> Tile:
    dx = 0.05
    nav = TileNav(lat_deg=44.0 + np.arange(rows) * dx / 111_000.0, lon_deg=np.full(rows, 9.0),
                  heading_deg=np.zeros(rows), altitude_m=np.full(rows, 10.0))
    px = np.random.default_rng(0).integers(1, 255, size=(rows, cols), dtype=np.uint8).astype(np.float32)
    return Tile(mission="big", leg=0, side="stbd", seq=0, pixels=px, kind="amplitude", range0_m=5.0, dr_m=0.05,
                dx_m=dx, slant=slant, ping_time=1.7e9 + 0.05 * np.arange(rows), nav=nav, wire_dtype="uint8")


def test_parse_refuses_a_tile_over_the_limit_naming_it():
    m = _tile(64, 128).to_map()
    assert Tile.from_map(m, max_pixels=64 * 128).shape == (64, 128)
    with pytest.raises(TileError, match=r"64 x 128 = 8192 pixels is more than node.max_tile_pixels = 8191") as e:
        Tile.from_map(m, max_pixels=8191)
    assert e.value.field == "shape" and "big/stbd" in str(e.value)


def test_setting_is_validated():
    assert NodeSettings().max_tile_pixels == 1 << 23
    for bad in (0, (1 << 28) + 1, 2.5):
        with pytest.raises(AtrError, match="node.max_tile_pixels"):
            NodeSettings(max_tile_pixels=bad)


_PEAK = ("import json, resource, subprocess, sys\n"
         "p = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
         "print(json.dumps({'rc': p.returncode, 'err': p.stderr, "
         "'peak_b': resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024}))\n")


def _replay_peak(log: Path, tmp: Path) -> dict:
    cmd = [sys.executable, "-c", _PEAK, sys.executable, "-m", "atr_node", "replay", str(log), "--publish", "none",
           "--speed", "max", "--online-calibration", "off"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp)
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_8192_square_tile_refused_under_budget(tmp_path):
    # before: processed, 4.8 GB peak; now refused and counted, the replay's peak far below 2 GiB
    log = tmp_path / "big.atrlog"
    with AtrLogWriter(log) as w:
        w.write(1.7e9, "sonar", _tile(8192, 8192).to_map())
    r = _replay_peak(log, tmp_path)
    assert r["rc"] == 0, r["err"][-2000:]
    assert "8192 x 8192 = 67108864 pixels is more than node.max_tile_pixels" in r["err"]
    assert "1 rejected" in r["err"] and "tile field shape x 1" in r["err"]
    assert "Traceback" not in r["err"]
    assert r["peak_b"] < 1 << 30, f"peak RSS {r['peak_b'] / 2**20:.0f} MiB"


def test_tile_at_the_limit_processed_under_budget(tmp_path):
    # 2048 x 4096 = 2^23 pixels: processed, peak near 0.9 GiB (budget 2 GiB)
    log = tmp_path / "limit.atrlog"
    with AtrLogWriter(log) as w:
        w.write(1.7e9, "sonar", _tile(2048, 4096).to_map())
    r = _replay_peak(log, tmp_path)
    assert r["rc"] == 0, r["err"][-2000:]
    assert "1 tiles in, 1 done, 0 rejected" in r["err"]
    assert r["peak_b"] < 2 * 2**30, f"peak RSS {r['peak_b'] / 2**20:.0f} MiB"
