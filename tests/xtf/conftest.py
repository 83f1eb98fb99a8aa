"""Fixtures of the XTF tests: the real recordings, their tiles, and a builder of small tiles."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from atr_node.io.xtf import XtfReader
from atr_node.records.tile import SensorInfo, Tile, TileNav

T0 = 1_700_000_000.0


@pytest.fixture(scope="session")
def iver2(real_data: Path) -> Path:
    return real_data / "xtf" / "scotsman-iver2.xtf"


@pytest.fixture(scope="session")
def nav_only(real_data: Path) -> Path:
    return real_data / "xtf" / "r2sonic-multibeam-nav-only.xtf"


@pytest.fixture(scope="session")
def iver2_read(iver2: Path):
    """(records, stats, tiles) of the Iver2 file read once, altitude as recorded (the tests
    compare the tiles with the file's own header fields; the image's altitude is tested in
    test_bottom_track and test_altitude_tiling)."""
    reader = XtfReader(iver2, altitude="altimeter")
    records = list(reader)
    tiles = [Tile.from_map(r.msg) for r in records if r.link == "sonar"]
    return records, reader.stats, tiles


def make_tile(side: str = "stbd", *, rows: int = 4, cols: int = 16, seq: int = 0, t0: float = T0,
              dtype: str = "uint16", slant: bool = True, nav: bool = True, rng=None, range0_m: float = 0.05,
              dr_m: float = 0.1, lat0: float = 48.0, mission: str = "synthetic") -> Tile:
    """A small tile with random pixels (integers for integer wire types, some no-data)."""
    rng = rng or np.random.default_rng(seq + (0 if side == "port" else 100))
    hi = {"uint16": 65535, "uint8": 255, "float32": 1e4}[dtype]
    px = rng.integers(1, hi, size=(rows, cols)).astype(np.float32) if dtype != "float32" else \
        rng.uniform(0.0, hi, size=(rows, cols)).astype(np.float32)
    px[0, 0] = np.nan
    ping_time = t0 + 0.13 * np.arange(rows)
    tn = None
    if nav:
        tn = TileNav(lat_deg=lat0 + 1e-6 * np.arange(rows), lon_deg=-68.0 - 1e-6 * np.arange(rows),
                     heading_deg=np.float32(10.5) + np.zeros(rows), altitude_m=np.float32(4.25) + np.zeros(rows))
    sensor = SensorInfo(frequency_hz=600e3, bandwidth_hz=30e3, tx_length_m=0.2, rx_length_m=1.2, n_rx=1, sas=False)
    return Tile(mission=mission, leg=2, side=side, seq=seq, pixels=px, kind="amplitude", range0_m=range0_m,
                dr_m=dr_m, dx_m=0.12, slant=slant, ping_time=ping_time, nav=tn, sensor=sensor, wire_dtype=dtype)


def run_cli(*args, timeout: float = 300):
    """``python -m atr_node ARGS`` in a subprocess (stdout and stderr captured as text)."""
    return subprocess.run([sys.executable, "-m", "atr_node", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)
