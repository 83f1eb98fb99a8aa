"""Shared fixtures: paths to the real recordings in ../shared/data/real and small tile builders."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
REAL_DATA = Path(os.environ.get("ATR_REAL_DATA", REPO.parent / "shared" / "data" / "real"))


@pytest.fixture(scope="session")
def real_data() -> Path:
    """Folder of the real third-party recordings (see its README for licences)."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real recordings not found at {REAL_DATA} (set ATR_REAL_DATA)")
    return REAL_DATA


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


SMALL_MISSION = """
[simulation]
mission_legs = 3
mission_leg_length_m = 70.0
mission_swath_m = 30.0
mission_targets = 5
mission_tile_pings = 128
mission_clutter_per_km2 = 1000.0

[node]
snapshot_every_tiles = 4
queue_tiles = 4
heartbeat_s = 0.2
"""
"""A 3-leg, 36-tile mission with 5 targets (a few seconds to generate, about 200 s of records),
and node settings that snapshot often; shared by the node, operators, reliability and
evaluation tests."""


@pytest.fixture(scope="session")
def small_mission(tmp_path_factory):
    """(settings, config path, MissionFiles) of :data:`SMALL_MISSION`, generated once a session."""
    from atr_node.config import load_settings
    from atr_node.simulation.mission import generate_mission

    d = tmp_path_factory.mktemp("small_mission")
    cfg = d / "small.toml"
    cfg.write_text(SMALL_MISSION)
    settings = load_settings(cfg)
    return settings, cfg, generate_mission(settings, d, seed=7)
