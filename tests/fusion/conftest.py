"""Scenes for the fusion tests: real tiles with straight-line nav, georeferenced by atr_node.geo."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from atr_node.config import FusionSettings
from atr_node.fusion import DetectionEvidence, DetectorObservation, EvidenceGrid, Observation
from atr_node.geo import MissionFrame, TileGeometry, tile_geometry
from atr_node.records.tile import Tile, TileNav

ORIGIN = (44.08, 9.85)


@pytest.fixture(scope="session")
def frame() -> MissionFrame:
    return MissionFrame("ltp", *ORIGIN)


def track_geometry(frame: MissionFrame, *, east0_m: float, north0_m: float, heading_deg: float, rows: int,
                   cols: int, dx_m: float = 0.1, dr_m: float = 0.1, range0_m: float = 20.0,
                   side: str = "stbd", leg: int = 1, t0: float = 1.7e9) -> TileGeometry:
    """Geometry of a ground-range tile of a straight track starting at (east0, north0)."""
    h = np.radians(heading_deg)
    i = np.arange(rows)
    e = east0_m + i * dx_m * np.sin(h)
    n = north0_m + i * dx_m * np.cos(h)
    lat, lon = frame.to_latlon(e, n)
    nav = TileNav(lat, lon, np.full(rows, heading_deg), np.full(rows, 14.0))
    tile = Tile(mission="test", leg=leg, side=side, seq=0, pixels=np.ones((rows, cols), np.float32),
                kind="intensity", range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, slant=False,
                ping_time=t0 + i * 0.1, nav=nav)
    return tile_geometry(tile, frame)


def pixel_of(geom: TileGeometry, east_m: float, north_m: float) -> tuple[int, int]:
    """Nearest pixel of a geometry to a point (brute force over the grid)."""
    e, n = geom.world_grid()
    k = int(np.argmin((e - east_m) ** 2 + (n - north_m) ** 2))
    return divmod(k, e.shape[1])


def step_pd(ranges_m: np.ndarray, *, near: float = 0.95, far: float = 0.1, split_m: float = 60.0) -> np.ndarray:
    """Hand-made Pd(r): ``near`` below ``split_m``, ``far`` beyond."""
    return np.where(ranges_m < split_m, near, far)


def observe(geom: TileGeometry, leg: int, t: float, views: dict[str, tuple[np.ndarray | None, np.ndarray,
            list[tuple[int, int, float]]]]) -> Observation:
    """Observation from {detector: (covered or None = all, pd (cols,), [(row, col, confidence)])}."""
    shape = (geom.east_m.size, geom.ranges_m.size)
    dets = []
    for name, (cov, pd, hits) in views.items():
        cov = np.ones(shape, bool) if cov is None else cov
        ev = tuple(DetectionEvidence(row=r, col=c, gamma=3.0, range_m=float(geom.ranges_m[c]), confidence=conf)
                   for r, c, conf in hits)
        dets.append(DetectorObservation(detector=name, covered=cov, pd=pd, detections=ev))
    return Observation(leg=leg, t=t, geometry=geom, detectors=tuple(dets))


@pytest.fixture
def make_grid() -> Callable[..., EvidenceGrid]:
    def make(**kw) -> EvidenceGrid:
        gate = kw.pop("gate_m", 3.0)
        return EvidenceGrid(FusionSettings(**kw), gate_m=gate)
    return make


TARGETS = ((50.0, -5.0), (70.0, 8.0), (100.0, 0.0))
LEGS = ((1, 0.0, 0.0), (2, 110.0, 180.0), (3, 30.0, 0.0), (4, 140.0, 180.0))  # leg, east0, heading
DETS = ("mf", "lac", "smf", "z")


def mission_observations(frame: MissionFrame, *, seed: int = 5, tiles_per_leg: int = 2,
                         rows: int = 400) -> list[Observation]:
    """A four-leg lawnmower over three targets, each leg cut into tiles, with hand-made
    detections (Pd(r) per detector, confidence 0.5-0.9) and a few false alarms."""
    rng = np.random.default_rng(seed)
    out = []
    per = rows // tiles_per_leg
    for leg, east0, heading in LEGS:
        north0 = -20.0 if heading == 0.0 else 20.0
        step = 0.1 if heading == 0.0 else -0.1
        for k in range(tiles_per_leg):
            g = track_geometry(frame, east0_m=east0, north0_m=north0 + k * per * step, heading_deg=heading,
                               rows=per, cols=700, leg=leg)
            views = {}
            for d in DETS:
                pd = step_pd(g.ranges_m, near=0.9, far=0.3)
                hits = []
                e, n = g.world_grid()
                for te, tn in TARGETS:
                    dist = (e - te) ** 2 + (n - tn) ** 2
                    idx = int(np.argmin(dist))
                    if dist.flat[idx] < 0.05 and rng.uniform() < 0.8:
                        r, c = divmod(idx, e.shape[1])
                        r = int(np.clip(r + rng.integers(-2, 3), 0, per - 1))
                        c = int(np.clip(c + rng.integers(-2, 3), 0, 699))
                        hits.append((r, c, float(rng.uniform(0.5, 0.9))))
                if rng.uniform() < 0.5:
                    hits.append((int(rng.integers(0, per)), int(rng.integers(0, 700)), 0.3))
                cov = np.ones((per, 700), bool)
                cov[:, :3] = False  # window edge: not covered
                views[d] = (cov, pd, hits)
            out.append(observe(g, leg, 1000.0 * leg + k, views))
    return out
