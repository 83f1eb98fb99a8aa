"""Shared helpers of the reliability tests: the tools loaded as modules, a small mission."""

from __future__ import annotations

import importlib.util
import sys
import tomllib
from pathlib import Path

import pytest

from atr_node.config import settings_from_dict

TOOLS = Path(__file__).resolve().parents[2] / "tools"

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


def load_tool(name: str):
    """Import ``tools/<name>.py`` as a module (the tools are scripts, not a package)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="package")
def small_mission(tmp_path_factory):
    """(settings, config path, MissionFiles) of a 3-leg, 36-tile mission (about 200 s of records)."""
    from atr_node.simulation.mission import generate_mission

    d = tmp_path_factory.mktemp("rel_mission")
    cfg = d / "small.toml"
    cfg.write_text(SMALL_MISSION)
    settings = settings_from_dict(tomllib.loads(SMALL_MISSION), path=str(cfg))
    return settings, cfg, generate_mission(settings, d, seed=7)
