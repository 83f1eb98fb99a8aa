"""Fixtures of the scale-out tests: tiny generated missions and a log split between two vehicles."""

from __future__ import annotations

from pathlib import Path

import pytest

from atr_node.config import load_settings
from atr_node.io.atrlog import AtrLogWriter, read_atrlog
from atr_node.simulation.mission import generate_mission

TINY = """
[simulation]
mission_legs = {legs}
mission_leg_length_m = 40.0
mission_swath_m = 30.0
mission_targets = 3
mission_tile_pings = 128
mission_clutter_per_km2 = 1000.0
"""


def tiny_settings(folder: Path, legs: int = 4):
    cfg = folder / "tiny.toml"
    cfg.write_text(TINY.format(legs=legs))
    return load_settings(cfg), cfg


def split_by_leg(src: Path, dst: Path, legs: set[int]) -> Path:
    """The recording one vehicle would have made surveying only ``legs``: every nav record,
    and the sonar tiles of those legs."""
    with AtrLogWriter(dst) as w:
        for rec in read_atrlog(src):
            if rec.link != "sonar" or int(rec.msg["leg"]) in legs:
                w.write_record(rec)
    return dst


@pytest.fixture(scope="session")
def four_leg_mission(tmp_path_factory):
    d = tmp_path_factory.mktemp("four_legs")
    settings, cfg = tiny_settings(d, legs=4)
    files = generate_mission(settings, d, seed=11)
    return settings, cfg, files


@pytest.fixture(scope="session")
def tiny_missions(tmp_path_factory):
    """Three 2-leg missions of different seeds over the same field."""
    d = tmp_path_factory.mktemp("tiny_missions")
    settings, cfg = tiny_settings(d, legs=2)
    return settings, cfg, [generate_mission(settings, d / f"m{s}", seed=s).atrlog for s in (1, 2, 3)]
