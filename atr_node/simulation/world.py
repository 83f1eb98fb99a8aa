"""The world of a synthetic mission: survey legs, targets, clutter and ripple fields.

:func:`plan_world` lays out, from one random generator, everything that stays the same on
every leg (SPEC section 4 targets, the clutter that makes false alarms, ripple patches) and
the legs themselves with their own navigation errors. Coordinates are metres east/north in
the local tangent plane at the mission origin. :mod:`.mission` renders it into tiles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..config import Settings
from .meshes import Mesh, builtin_mesh, load_mesh
from .seabed import RippleField

EPOCH = datetime(2026, 5, 4, 9, 0, 0, tzinfo=timezone.utc).timestamp()
"""Start of every simulated mission (UNIX seconds)."""


@dataclass(frozen=True)
class WorldObject:
    """A target or a piece of clutter fixed in the world."""

    shape: str
    east_m: float
    north_m: float
    heading_deg: float
    """Azimuth of the object's x axis, clockwise from north."""
    burial_m: float
    mesh: Mesh = field(repr=False, compare=False)


@dataclass(frozen=True)
class Leg:
    """One survey line: true start, heading, timing and the nav error of this leg."""

    index: int
    start_east_m: float
    start_north_m: float
    heading_deg: float
    pings: int
    t0: float
    nav_offset_east_m: float
    nav_offset_north_m: float
    nav_drift_east_m: float
    """Extra east error at the end of the leg (linear along it)."""
    nav_drift_north_m: float

    @property
    def along(self) -> np.ndarray:
        """Unit vector (east, north) along the track."""
        h = math.radians(self.heading_deg)
        return np.array([math.sin(h), math.cos(h)])

    def side(self, side: str) -> np.ndarray:
        """Unit vector (east, north) across the track to ``side`` (georef convention)."""
        h = math.radians(self.heading_deg)
        stbd = np.array([math.cos(h), -math.sin(h)])
        return stbd if side == "stbd" else -stbd


def _clutter(rng: np.random.Generator) -> Mesh:
    """Natural and man-made clutter: a boulder (squashed sphere, 0.3-1 m), a block
    (0.3-1 m) or debris (a pipe 1-4 m long, 0.1-0.3 m thick) -- target-sized or target-shaped
    false-alarm sources, none of which is truth."""
    u = rng.random()
    if u < 0.6:
        m = builtin_mesh("sphere", radius_m=0.5, segments=10)
        s = np.array([rng.uniform(0.3, 1.0), rng.uniform(0.3, 1.0), rng.uniform(0.2, 0.6)])
        return Mesh(m.vertices_m * s, m.faces, "rock")  # scaling keeps the base on the seabed
    if u < 0.85:
        m = builtin_mesh("box", length_m=rng.uniform(0.3, 1.0), width_m=rng.uniform(0.3, 0.8),
                         height_m=rng.uniform(0.1, 0.4))
        return Mesh(m.vertices_m, m.faces, "block")
    m = builtin_mesh("cylinder", length_m=rng.uniform(1.0, 4.0), radius_m=rng.uniform(0.05, 0.15), segments=8)
    return Mesh(m.vertices_m, m.faces, "debris")


def _axis_error(rng: np.random.Generator, sigma: float) -> float:
    """A normal draw truncated at 2 sigma: INS errors of aided survey legs, without the rare
    wild draw that would make one seed's demo unrepresentative."""
    return float(np.clip(rng.normal(0.0, sigma), -2.0 * sigma, 2.0 * sigma))


def _target_mesh(settings: Settings, shape: str) -> Mesh:
    """A built-in shape, or a mesh file (``.stl``/``.obj``: relative to the settings file,
    else to the working folder); the truth names a file's target by its stem."""
    if not shape.lower().endswith((".stl", ".obj")):
        return builtin_mesh(shape)
    p = Path(shape)
    if not p.is_absolute() and settings.source and (Path(settings.source).parent / p).exists():
        p = Path(settings.source).parent / p
    return load_mesh(p)


def _spread(rng: np.random.Generator, n: int, box: tuple[float, float, float, float], min_sep_m: float,
            avoid: list[tuple[float, float]] = ()) -> list[tuple[float, float]]:
    e0, e1, n0, n1 = box
    pts: list[tuple[float, float]] = []
    others = list(avoid)
    for _ in range(50 * max(n, 1)):
        if len(pts) >= n:
            break
        p = (float(rng.uniform(e0, e1)), float(rng.uniform(n0, n1)))
        if all((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 >= min_sep_m ** 2 for q in pts + others):
            pts.append(p)
    return pts


def plan_world(settings: Settings, rng: np.random.Generator, *, hard: bool = False,
               n_targets: int | None = None
               ) -> tuple[list[Leg], list[WorldObject], list[WorldObject], list[RippleField]]:
    """Legs, targets, clutter and ripple fields of a mission (no pixels yet)."""
    sim, sensor = settings.simulation, settings.sensor
    sw, L = sim.mission_swath_m, sim.mission_leg_length_m
    n_pings = int(round(L / sensor.dx_m))
    turn_s = sw / sim.mission_speed_m_s + 30.0
    legs = []
    t = EPOCH
    sigma = sim.mission_nav_error_m / math.sqrt(2.0)  # per axis, for a horizontal 1-sigma
    for k in range(sim.mission_legs):
        north_first = k % 2 == 0
        legs.append(Leg(index=k, start_east_m=k * sw, start_north_m=0.0 if north_first else L,
                        heading_deg=0.0 if north_first else 180.0, pings=n_pings, t0=t,
                        nav_offset_east_m=_axis_error(rng, sigma), nav_offset_north_m=_axis_error(rng, sigma),
                        nav_drift_east_m=_axis_error(rng, 0.35 * sigma),
                        nav_drift_north_m=_axis_error(rng, 0.35 * sigma)))
        t += n_pings * sensor.dx_m / sim.mission_speed_m_s + turn_s
    span_e = (sim.mission_legs - 1) * sw
    # Targets: mostly between the outer legs (seen twice), a few beyond them (seen once).
    tbox = (-0.3 * sw, span_e + 0.3 * sw, 12.0, L - 12.0) if span_e > 0 else (-0.9 * sw, 0.9 * sw, 12.0, L - 12.0)
    n_t = sim.mission_targets if n_targets is None else n_targets
    meshes = {name: _target_mesh(settings, name) for name in sim.mission_shapes}
    tpos = _spread(rng, n_t, tbox, 12.0)
    targets = []
    for i, (e, n) in enumerate(tpos):
        mesh = meshes[sim.mission_shapes[i % len(sim.mission_shapes)]]
        burial = float(rng.uniform(0.0, 0.25 if hard else 0.1)) if rng.random() < 0.3 else 0.0
        targets.append(WorldObject(mesh.name, e, n, float(rng.uniform(0, 360)), burial, mesh))
    area_km2 = (span_e + 2 * sw) * L / 1e6
    n_c = int(round(sim.mission_clutter_per_km2 * (3.0 if hard else 1.0) * area_km2))
    cpos = _spread(rng, n_c, (-sw, span_e + sw, 0.0, L), 1.5, avoid=[(o.east_m, o.north_m) for o in targets])
    clutter = []
    for e, n in cpos:
        m = _clutter(rng)
        clutter.append(WorldObject(m.name, e, n, float(rng.uniform(0, 360)), 0.0, m))
    ripples: list[RippleField] = []
    if sim.mission_ripples or hard or sim.seabed == "sand":
        for _ in range(max(2, int(round(6 * area_km2 / 0.05)))):
            ripples.append(RippleField(east_m=float(rng.uniform(-sw, span_e + sw)), north_m=float(rng.uniform(0, L)),
                                       radius_m=float(rng.uniform(15, 40)), wavelength_m=float(rng.uniform(0.6, 1.2)),
                                       crest_azimuth_deg=float(rng.uniform(0, 180)),
                                       depth=float(rng.uniform(0.4, 0.8) if hard else rng.uniform(0.2, 0.5))))
    return legs, targets, clutter, ripples


def leg_positions(leg: Leg, rows: np.ndarray, dx_m: float) -> tuple[np.ndarray, np.ndarray]:
    """True (east_m, north_m) of pings ``rows`` (fractional allowed) of a leg."""
    s = rows * dx_m
    u = leg.along
    return leg.start_east_m + s * u[0], leg.start_north_m + s * u[1]


def leg_nav_error(leg: Leg, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(east_m, north_m) error of the recorded nav at pings ``rows``: offset plus linear drift."""
    f = rows / max(leg.pings - 1, 1)
    return leg.nav_offset_east_m + f * leg.nav_drift_east_m, leg.nav_offset_north_m + f * leg.nav_drift_north_m
