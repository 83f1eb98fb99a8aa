"""Synthetic multi-leg missions: a lawnmower survey over a seabed with targets and clutter.

:func:`generate_mission` writes ``mission.atrlog`` (ICD section 4: sonar tiles in ground range
with their per-ping ``nav`` map, the INS as NMEA GGA/HDT/DPT/ZDA at 5 Hz and CAN frames of
``config/atr_node.dbc``) and ``truth.csv`` (ICD section 5), plus ``clutter.csv`` (rocks, blocks, debris,
which are not truth) for diagnostics.

The world is a local tangent plane at the mission origin (metres east/north). Legs run
north and south alternately, ``swath`` apart, so the strip between two legs is seen by both,
from ranges d and swath - d. Every leg has its own navigation error (an offset plus a drift
along the leg): the recorded nav is the truth plus that error, as an INS would give. Targets
and clutter are fixed in the world and ray-traced into every tile that sees them, with the
geometry of that leg (range, aspect, side). The seabed is K-distributed with a range gain
that is not flat, ripple patches fixed in the world (``mission_ripples``, sand or ``hard``), a
nadir gap and ping drop-outs.
"""

from __future__ import annotations

import csv
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Settings
from ..errors import AtrError
from ..geo.frame import MissionFrame
from ..io.atrlog import AtrLogWriter
from ..records.tile import SensorInfo, Tile, TileNav
from .inject import Placement, inject_targets
from .ins import NAV_RATE_HZ, Record, ins_records
from .seabed import dropout_rows, gain_curve, ripple_modulation, seabed_pixels
from .world import EPOCH, Leg, WorldObject, leg_nav_error, leg_positions, plan_world

log = logging.getLogger(__name__)

NADIR_GAP_M = 2.0
TILE_LATENCY_S = 0.3
K_ORDER = {"mud": 20.0, "silt": 10.0, "sand": 6.0, "gravel": 4.0, "rock": 2.5}
"""K-distribution order of the seabed texture by type: rougher seabeds have heavier tails."""


@dataclass(frozen=True)
class MissionFiles:
    """What :func:`generate_mission` wrote."""

    out_dir: Path
    atrlog: Path
    truth: Path
    clutter: Path
    name: str
    legs: int
    tiles: int
    targets: int
    clutter_objects: int
    records: int
    duration_s: float


def _placements(leg: Leg, side: str, objects: list[WorldObject], row0: int, rows: int, dx_m: float,
                max_range_m: float) -> list[Placement]:
    u, v = leg.along, leg.side(side)
    out = []
    for o in objects:
        d = np.array([o.east_m - leg.start_east_m, o.north_m - leg.start_north_m])
        row = float(d @ u) / dx_m - row0
        rng_m = float(d @ v)
        if not (-40 <= row <= rows + 40 and 0.0 < rng_m < max_range_m + 2.0):
            continue
        h = math.radians(o.heading_deg)
        a = np.array([math.sin(h), math.cos(h)])
        rel = math.degrees(math.atan2(float(a @ v), float(a @ u)))
        out.append(Placement(o.shape, row=row, range_m=rng_m, heading_deg=rel, burial_m=o.burial_m, mesh=o.mesh))
    return out


def altitude_at(settings: Settings, t: np.ndarray | float) -> np.ndarray:
    """Vehicle altitude: the nominal one with a slow +-0.4 m swell of the terrain-following
    loop (period 240 s), so tiles differ in altitude as aboard."""
    return settings.sensor.altitude_m + 0.4 * np.sin(2.0 * np.pi * (np.asarray(t, dtype=np.float64) - EPOCH) / 240.0)


def _ins_for_leg(legs: list[Leg], k: int, settings: Settings, frame: MissionFrame, t_end: float) -> list[Record]:
    """INS records from the start of leg k until ``t_end``, through the turn to the next leg."""
    sim, sensor = settings.simulation, settings.sensor
    leg = legs[k]
    dt_ping = sensor.dx_m / sim.mission_speed_m_s
    t_leg_end = leg.t0 + (leg.pings - 1) * dt_ping
    times = np.arange(leg.t0, t_end, 1.0 / NAV_RATE_HZ)
    rows = np.clip((times - leg.t0) / dt_ping, 0, leg.pings - 1)
    e, n = leg_positions(leg, rows, sensor.dx_m)
    de, dn = leg_nav_error(leg, rows)
    e, n = e + de, n + dn
    hdg = np.full(times.size, leg.heading_deg)
    turn = times > t_leg_end
    if k + 1 < len(legs) and turn.any():  # straight to the next leg's (reported) start
        nxt = legs[k + 1]
        f = np.clip((times[turn] - t_leg_end) / (nxt.t0 - t_leg_end), 0.0, 1.0)
        e[turn] = e[turn] + f * (nxt.start_east_m + nxt.nav_offset_east_m - e[turn])
        n[turn] = n[turn] + f * (nxt.start_north_m + nxt.nav_offset_north_m - n[turn])
        sign = 1.0 if leg.heading_deg == 0.0 else -1.0  # turning towards the east, where the next leg is
        hdg[turn] = (leg.heading_deg + sign * 180.0 * f) % 360.0
    lat, lon = frame.to_latlon(e, n)
    alt = altitude_at(settings, times)
    return ins_records(times, lat, lon, hdg, altitude_m=alt, depth_m=sim.depth_m - alt, leg=leg.index,
                       survey=~turn)


def generate_mission(settings: Settings, out_dir: str | Path, *, seed: int, name: str | None = None,
                     hard: bool = False, n_targets: int | None = None, links: bool = True) -> MissionFiles:
    """Simulate a lawnmower mission and write ``mission.atrlog``, ``truth.csv``, ``clutter.csv``.

    Parameters
    ----------
    settings
        ``simulation.mission_*`` keys size the mission; ``sensor`` gives pixels and altitude.
    out_dir
        Folder to write into (created).
    seed
        Everything (layout, seabed, speckle, nav errors) follows from it.
    name
        Mission name in the tiles (default ``sim-<seed>``).
    hard
        Dense clutter (x3), strong ripple fields, rougher seabed, deeper burial.
    n_targets
        Overrides ``simulation.mission_targets``.
    links
        Also write the INS as NMEA and CAN records (False: tiles with nav only).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sim, sensor = settings.simulation, settings.sensor
    name = name or f"sim-{seed}"
    rng = np.random.default_rng(seed)
    frame = MissionFrame("ltp", sim.mission_origin_lat_deg, sim.mission_origin_lon_deg)
    legs, targets, clutter, ripples = plan_world(settings, rng, hard=hard, n_targets=n_targets)
    objects = targets + clutter
    dx, dr = sensor.dx_m, sensor.dr_m
    cols = int(round(sim.mission_swath_m / dr)) + 1
    ranges = dr * np.arange(cols)
    dt_ping = dx / sim.mission_speed_m_s
    info = SensorInfo(frequency_hz=sensor.frequency_hz, bandwidth_hz=sensor.bandwidth_hz,
                      tx_length_m=sensor.tx_length_m, rx_length_m=sensor.rx_length_m, n_rx=sensor.n_rx,
                      sas=sensor.sas)
    seq = {"port": 0, "stbd": 0}
    n_tiles = 0
    k_order = K_ORDER[sim.seabed] / (2.0 if hard else 1.0)
    path = out / "mission.atrlog"
    t_last = EPOCH
    with AtrLogWriter(path, flush_every=64) as writer:
        for leg in legs:
            t_next = legs[leg.index + 1].t0 if leg.index + 1 < len(legs) else leg.t0 + leg.pings * dt_ping + 2.0
            records: list[Record] = _ins_for_leg(legs, leg.index, settings, frame, t_next) if links else []
            for row0 in range(0, leg.pings, sim.mission_tile_pings):
                nrow = min(sim.mission_tile_pings, leg.pings - row0)
                rows = np.arange(row0, row0 + nrow, dtype=np.float64)
                pe, pn = leg_positions(leg, rows, dx)
                ne, nn = leg_nav_error(leg, rows)
                lat, lon = frame.to_latlon(pe + ne, pn + nn)
                ping_time = leg.t0 + rows * dt_ping
                alt_ping = altitude_at(settings, ping_time)
                nav = TileNav(lat_deg=lat, lon_deg=lon, heading_deg=np.full(nrow, leg.heading_deg % 360.0),
                              altitude_m=alt_ping)
                # The tile is rendered at its mean altitude (the swell is slow against a tile).
                alt = float(alt_ping.mean())
                g = gain_curve(ranges, altitude_m=alt, max_range_m=sim.mission_swath_m)
                lost = dropout_rows(nrow, rng)
                for j, side in enumerate(("port", "stbd")):
                    px = seabed_pixels(rows=nrow, cols=cols, range0_m=0.0, dr_m=dr, altitude_m=alt, rng=rng,
                                       k_order=k_order, max_range_m=sim.mission_swath_m)
                    if ripples:
                        v = leg.side(side)
                        we = pe[:, None] + ranges[None, :] * v[0]
                        wn = pn[:, None] + ranges[None, :] * v[1]
                        look = math.degrees(math.atan2(v[0], v[1]))
                        px *= ripple_modulation(we, wn, np.full((nrow, 1), look), ripples)
                    pl = _placements(leg, side, objects, row0, nrow, dx, sim.mission_swath_m)
                    if pl:
                        px, _ = inject_targets(px, range0_m=0.0, dr_m=dr, dx_m=dx, altitude_m=alt, placements=pl,
                                               rng=rng, sensor=sensor, simulation=sim, template=settings.template, g=g)
                    px[:, ranges < NADIR_GAP_M] = np.nan
                    px[lost] = np.nan
                    tile = Tile(mission=name, leg=leg.index, side=side, seq=seq[side], pixels=px, kind="intensity",
                                range0_m=0.0, dr_m=dr, dx_m=dx, slant=False, ping_time=ping_time, nav=nav, sensor=info)
                    seq[side] += 1
                    n_tiles += 1
                    records.append((float(ping_time[-1]) + TILE_LATENCY_S + 0.01 * j, "sonar", tile.to_map()))
            records.sort(key=lambda r: r[0])
            for t, link, msg in records:
                if t < t_last:
                    raise AtrError(f"internal: arrival times went back ({t} < {t_last}) in leg {leg.index}")
                writer.write(t, link, msg)
                t_last = t
        n_records = writer.records
    truth = out / "truth.csv"
    _write_objects(truth, targets, legs, frame, settings)
    clutter_path = out / "clutter.csv"
    _write_objects(clutter_path, clutter, legs, frame, settings)
    log.info("mission %s: %d legs, %d tiles, %d targets, %d clutter objects -> %s", name, len(legs), n_tiles,
             len(targets), len(clutter), path)
    return MissionFiles(out_dir=out, atrlog=path, truth=truth, clutter=clutter_path, name=name, legs=len(legs),
                        tiles=n_tiles, targets=len(targets), clutter_objects=len(clutter), records=n_records,
                        duration_s=t_last - EPOCH)


def _write_objects(path: Path, objects: list[WorldObject], legs: list[Leg], frame: MissionFrame,
                   settings: Settings) -> None:
    """CSV of world objects (ICD section 5): lat_deg, lon_deg, shape, then east/north in the
    mission's local tangent plane, heading, burial, height, and per leg the side and ground
    range it was seen at (empty when outside that leg's swath)."""
    sw = settings.simulation.mission_swath_m
    header = ["lat_deg", "lon_deg", "shape", "east_m", "north_m", "heading_deg", "burial_m", "height_m"]
    for leg in legs:
        header += [f"leg{leg.index}_side", f"leg{leg.index}_range_m"]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for o in objects:
            lat, lon = frame.to_latlon(o.east_m, o.north_m)
            lo, hi = o.mesh.bounds_m
            row: list[Any] = [f"{float(lat):.8f}", f"{float(lon):.8f}", o.shape, f"{o.east_m:.3f}", f"{o.north_m:.3f}",
                              f"{o.heading_deg % 360:.1f}", f"{o.burial_m:.3f}", f"{hi[2] - lo[2] - o.burial_m:.3f}"]
            for leg in legs:
                d = np.array([o.east_m - leg.start_east_m, o.north_m - leg.start_north_m])
                r_st = float(d @ leg.side("stbd"))
                along = float(d @ leg.along)
                seen = 0 <= along <= leg.pings * settings.sensor.dx_m and NADIR_GAP_M <= abs(r_st) <= sw
                row += [("stbd" if r_st > 0 else "port") if seen else "", f"{abs(r_st):.2f}" if seen else ""]
            w.writerow(row)
