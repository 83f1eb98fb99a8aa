"""Marked hits on XTF recordings, located in the tiles and on the Earth.

A ``.hits`` file (as OpenSidescan writes them next to ``<name>.xtf``) holds one hit a line::

    <channel> <sample> <ping>

``channel`` is the index of the channel in the ping packet (its side comes from the file
header's ``XTFChanInfo.TypeOfChannel``), ``sample`` the sample index as stored in the file
(starboard from the nadir out, port from far range in), ``ping`` the index of the sonar ping
packet in the file, all from 0. :func:`locate_hit` turns one into the row and column of the
slant-range tile, its ground range (SPEC section 0: ``r = sqrt(R^2 - H^2)`` with the ping's
altitude) and its WGS84 position (``atr_node.geo``). Surveyed reference points are read from
CSV files with ``latitude``/``longitude`` (or ``lat_deg``/``lon_deg``) columns.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError
from ..geo import MissionFrame, tile_geometry
from ..records.tile import Tile
from .xtf_packets import CHANNEL_SIDES, read_file_header


@dataclass(frozen=True)
class XtfHit:
    channel: int
    sample: int
    ping: int


@dataclass(frozen=True)
class HitLocation:
    """Where a hit lies: in its slant tile, its ground-range tile and on the Earth."""

    side: str
    tile_index: int
    """Index of the tile among the tiles given."""
    row: int
    slant_col: int
    slant_range_m: float
    altitude_m: float
    ground_range_m: float
    """NaN when the slant range is shorter than the altitude (water column)."""
    ground_col: float
    """Fractional column in ``ground_tile``."""
    ground_tile: Tile
    lat_deg: float
    lon_deg: float


def read_hits(path: str | os.PathLike[str]) -> list[XtfHit]:
    """The hits of a ``.hits`` file; a malformed line raises ValueError naming it."""
    hits = []
    with open(path, encoding="ascii") as fh:
        for n, line in enumerate(fh, 1):
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            if len(parts) != 3 or not all(p.isdigit() for p in parts):
                raise ValueError(f"{path}:{n}: expected '<channel> <sample> <ping>' (integers), got {line.strip()!r}")
            hits.append(XtfHit(*(int(p) for p in parts)))
    return hits


def channel_sides(path: str | os.PathLike[str]) -> list[str | None]:
    """Side of each channel index of the file's pings (None: not a side-scan channel)."""
    with open(path, "rb") as fh:
        header = read_file_header(fh, str(path))
    n = header.NumberOfSonarChannels
    return [CHANNEL_SIDES.get(header.ChanInfo[i].TypeOfChannel) for i in range(min(n, 6))]


def read_survey_csv(path: str | os.PathLike[str]) -> list[tuple[str, float, float]]:
    """(name, lat_deg, lon_deg) of each row of a surveyed-points CSV."""
    out = []
    with open(path, newline="", encoding="utf-8") as fh:
        for n, row in enumerate(csv.DictReader(fh, skipinitialspace=True), 2):
            lat = row.get("latitude", row.get("lat_deg"))
            lon = row.get("longitude", row.get("lon_deg"))
            if lat is None or lon is None:
                raise ValueError(f"{path}:{n}: expected latitude/longitude or lat_deg/lon_deg columns")
            out.append((row.get("name", str(n - 1)), float(lat), float(lon)))
    return out


def locate_hit(tiles: list[Tile], hit: XtfHit, sides: list[str | None], frame: MissionFrame | None = None) -> HitLocation:
    """Locate a hit in slant-range tiles read from its XTF file (every ping kept, file order).

    Parameters
    ----------
    tiles
        The file's tiles, both sides, in stream order (``XtfReader`` with no ping dropped).
    hit
        The hit.
    sides
        :func:`channel_sides` of the file.
    frame
        Metric frame for georeferencing; default UTM at the hit's ping.
    """
    if not 0 <= hit.channel < len(sides) or sides[hit.channel] is None:
        raise GeometryError(f"hit channel {hit.channel}: not a side-scan channel of the file ({sides})")
    side = sides[hit.channel]
    first_row = 0
    for k, tile in enumerate(t for t in tiles if t.side == side):
        if first_row + tile.rows > hit.ping:
            break
        first_row += tile.rows
    else:
        raise GeometryError(f"hit ping {hit.ping}: the {side} tiles hold {first_row} pings")
    index = [i for i, t in enumerate(tiles) if t.side == side][k]
    row = hit.ping - first_row
    if not 0 <= hit.sample < tile.cols:
        raise GeometryError(f"hit sample {hit.sample}: the {side} channel has {tile.cols} samples")
    col = tile.cols - 1 - hit.sample if side == "port" else hit.sample  # tiles count from the nadir
    if tile.nav is None:
        raise GeometryError(f"hit ping {hit.ping}: no navigation in the ping header")
    r = tile.range0_m + col * tile.dr_m
    h = float(tile.nav.altitude_m[row])
    g = math.sqrt(r * r - h * h) if r >= h else math.nan
    ground = tile.ground_range()
    gcol = (g - ground.range0_m) / ground.dr_m
    frame = frame or MissionFrame("utm", float(tile.nav.lat_deg[row]), float(tile.nav.lon_deg[row]))
    lat = lon = math.nan
    if math.isfinite(g):
        e, n = tile_geometry(ground, frame).world(row, gcol)
        la, lo = frame.to_latlon(e, n)
        lat, lon = float(np.asarray(la)), float(np.asarray(lo))
    return HitLocation(side=side, tile_index=index, row=row, slant_col=col, slant_range_m=r, altitude_m=h,
                       ground_range_m=g, ground_col=gcol, ground_tile=ground, lat_deg=lat, lon_deg=lon)
