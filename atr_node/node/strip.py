"""Joining a leg's tiles into a strip, so that core scores do not depend on tile cuts.

SPEC section 0: detectors see a margin of at least half the largest window around each tile
core, and evidence is deposited from the core only. Tiles span the whole swath in range, so
cuts are along-track (rows) only. For a margin of ``m`` rows, each tile that arrives
finalises a core shifted back by ``m`` rows: the rows whose ``m`` following rows are known::

    context (m rows, already emitted) | core (emitted now) | future (m rows, emitted next time)

At the end of a leg (another leg on this side, a gap in ping time, a change of ping spacing,
or the end of the input) the rows still pending are emitted with no future rows, as the whole
strip would score them.

Units do not depend on where tiles are cut (SPEC section 0; issue 21): with ``unit_rows`` the
strip is cut into cores of that many rows counted from the strip's first ping, each emitted
once its ``m`` following rows are known (the strip's first unit may be longer: its own pings
are all the background b(j) it has), whatever the tiles that brought them (one-ping tiles
or one long tile give the same units, so the same scores, background updates, detections and
evidence). The margin and the unit length of a strip come from its own ping spacing (the
``geometry`` callable), not from the first tile the node ever saw; a tile whose ``dx_m``
differs from its strip's by more than :data:`DX_TOLERANCE` starts a new strip, counted in
``breaks``. The latency this adds is up to ``unit_rows + m`` pings (``m`` without ``unit_rows``:
the core is then all pending rows but the last ``m``, and depends on the cut).

Units carry the ping times and per-ping nav of every row, and the column axis of the leg:
later tiles are put on the first tile's axis (same spacing; shifted and NaN-padded by whole
columns).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import TileError
from ..records.tile import Tile, TileNav

DX_TOLERANCE = 0.1
"""Relative difference of ping spacing beyond which a tile starts a new strip: speed jitter
in a recorder's per-tile ``dx_m`` stays in its strip, a tile of another spacing (100 m: a
far-away tile) gets its own margin instead of setting the strip's."""

BREAK_DX = "ping spacing (dx_m) changed"
BREAK_GAP = "gap in ping time"


@dataclass(frozen=True, eq=False)
class StripUnit:
    """Rows to score: ``pixels[core]`` is the core, the rows around it are margin."""

    mission: str
    leg: int
    side: str
    seq: int
    """seq of the newest tile that contributed."""
    pixels: np.ndarray
    ping_time: np.ndarray
    nav: TileNav
    core: slice
    range0_m: float
    dr_m: float
    dx_m: float
    kind: str
    tiles: tuple[int, ...]
    """seq of the tiles whose rows are in the core."""
    completed: tuple[int, ...] = ()
    """seq of the tiles whose last rows are in this core: their evidence is complete with it.
    One entry per tile, even when tiles repeat a seq (tiles are told apart by their arrival
    number, not their seq): ``len(completed)`` is the number of tiles done."""
    lookahead: np.ndarray | None = None
    """The first unit of a strip only (when the strip's first rows ``k0`` exceed its unit
    rows): those first rows, this core's and the ones after it, whose column statistics the
    unit is scored against, as b(j) and m(j) (its own core is too few pings where one object
    fills much of it). None for every other unit."""
    closes_leg: bool = False
    """The last unit of a leg's strips (set by the node when a tile of another leg arrives):
    the leg's evidence is complete once it is fused."""
    full_scale: float | None = None
    """The recording's clip level (:attr:`~atr_node.records.tile.Tile.saturation` of the strip's
    tiles, in ``kind``); None: unknown."""

    @property
    def core_rows(self) -> int:
        return self.core.stop - self.core.start

    def core_tile(self) -> Tile:
        """The core as a ground-range tile (for georeferencing)."""
        return Tile(self.mission, self.leg, self.side, self.seq, self.pixels[self.core], self.kind, self.range0_m,
                    self.dr_m, self.dx_m, False, self.ping_time[self.core], nav=self.nav.slice(self.core),
                    full_scale=self.full_scale)


class _Rows:
    """Rows of one leg and side kept between tiles: pixels, times, nav, origin tile's arrival
    number (``src``: the assembler numbers the tiles it is given, 0, 1, 2, ...; a seq may repeat).

    Appended blocks are kept as they come and joined once, when a unit is cut (:meth:`cat`):
    a tile's pixels are copied once on their way into a unit, not once more into the pending
    rows (8 MB per 2-Mpx tile)."""

    def __init__(self, cols: int) -> None:
        self.cols = cols
        self._blocks: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._n = 0

    @classmethod
    def of(cls, px: np.ndarray, t: np.ndarray, nav: np.ndarray, src: np.ndarray) -> "_Rows":
        out = cls(px.shape[1])
        out._blocks = [(px, t, nav, src)] if len(t) else []
        out._n = int(len(t))
        return out

    def append(self, px, t, nav, seq) -> None:
        if len(t):
            self._blocks.append((px, np.asarray(t), np.asarray(nav), np.full(len(t), seq, dtype=np.int64)))
            self._n += len(t)

    def _joined(self, i: int, dtype, width: int) -> np.ndarray:
        parts = [b[i] for b in self._blocks]
        if not parts:
            return np.empty((0, width) if width else (0,), dtype)
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    @property
    def px(self) -> np.ndarray:
        return self._joined(0, np.float32, self.cols)

    @property
    def t(self) -> np.ndarray:
        return self._joined(1, np.float64, 0)

    @property
    def nav(self) -> np.ndarray:
        return self._joined(2, np.float64, 4)

    @property
    def src(self) -> np.ndarray:
        return self._joined(3, np.int64, 0)

    def cat(self, other: "_Rows", alloc: Callable[[tuple[int, int]], np.ndarray] | None = None) -> "_Rows":
        """These rows then ``other``'s, each array joined into one block (one copy; the
        pixels into ``alloc((rows, cols))`` if given)."""
        both = _Rows(self.cols)
        both._blocks = self._blocks + other._blocks
        both._n = self._n + other._n
        parts = [b[0] for b in both._blocks]
        if alloc is None:
            px = both.px
        else:
            px = alloc((both._n, self.cols))
            if parts:
                np.concatenate(parts, out=px)
        return _Rows.of(px, both.t, both.nav, both.src)

    def take(self, rows: slice, *, copy: bool = False) -> "_Rows":
        px = self.px[rows]
        return _Rows.of(px.copy() if copy else px, self.t[rows], self.nav[rows], self.src[rows])

    def __len__(self) -> int:
        return self._n


@dataclass
class _LegState:
    mission: str
    leg: int
    side: str
    range0_m: float
    dr_m: float
    dx_m: float
    kind: str
    cols: int
    last_seq: int
    last_time: float
    m: int
    """Margin rows of this strip (from its ping spacing)."""
    k: int | None
    """Core rows of each unit (None: all pending rows but the margin)."""
    context: _Rows
    pending: _Rows
    seqs: dict[int, int]
    """Arrival number -> seq of the tiles with rows in ``pending`` (``src`` holds the number)."""
    k0: int | None = None
    """Core rows of the strip's first unit (None: ``k``): longer, so that the background b(j)
    and median m(j) a strip starts from are not made of a few metres of seabed."""
    units: int = 0
    """Units emitted from this strip so far."""
    full_scale: float | None = None
    """The lowest saturation of the strip's tiles (None: unknown)."""


def _nav_array(tile: Tile) -> np.ndarray:
    n = tile.nav
    return np.stack([n.lat_deg, n.lon_deg, n.heading_deg, n.altitude_m], axis=1)


class StripAssembler:
    """Turns each (leg, side)'s ground-range tiles into :class:`StripUnit` with margins.

    Parameters
    ----------
    margin_rows
        ``m``: rows of context the detectors need on each side of a core row.
    max_gap_s
        A gap in ping time larger than this starts a new strip (no context across it), also
        within a tile.
    alloc
        Memory for each unit's pixels (see the attribute).
    geometry
        ``geometry(tile) -> (margin rows, unit rows or None[, first unit rows])`` for a strip
        starting with ``tile`` (the node: from the tile's ``dx_m`` and the settings); None:
        ``margin_rows`` and no fixed units. The first unit of a strip may be longer than the
        others (``node.first_unit_length_m``).
    """

    def __init__(self, margin_rows: int, *, max_gap_s: float = 5.0,
                 alloc: Callable[[tuple[int, int]], np.ndarray] | None = None,
                 geometry: Callable[[Tile], tuple[int, int | None]] | None = None) -> None:
        self.m = int(margin_rows)
        """Margin rows without ``geometry`` (and of snapshots from before it)."""
        self.geometry = geometry
        self.max_gap_s = float(max_gap_s)
        self._uncounted: set[int] = set()
        """Arrival numbers of the parts of a tile split at a gap but its last: not a tile done."""
        self.breaks: Counter = Counter()
        """Strips ended early, by reason (:data:`BREAK_DX`, :data:`BREAK_GAP`)."""
        self._legs: dict[str, _LegState] = {}
        self._next = 0
        """Arrival number of the next tile pushed: what tells tiles apart in the rows (``src``)."""
        self.seq_repeats = 0
        """Tiles whose seq did not increase on the previous tile of their strip (ICD section 1:
        +1 per tile and side); they are still joined and counted by arrival."""
        self.alloc = alloc
        """Memory for each unit's pixels, (rows, cols) float32 (None: a new array): the node
        gives shared memory its worker reads in place (``atr_node.node.pixelshm``). The
        assembler keeps no view of it once the unit is out."""

    def push(self, tile: Tile, *, _counted: bool = True) -> list[StripUnit]:
        """Take a ground-range tile with nav; return the units it completes (0, 1 or more)."""
        if tile.slant or tile.nav is None:
            raise TileError("the strip needs ground range and per-ping nav", tile=tile.ident)
        gaps = np.flatnonzero(np.diff(tile.ping_time) > self.max_gap_s) + 1
        if gaps.size:
            # a gap inside the tile ends the strip there, as it would between tiles: the
            # strips (and units) must not depend on where the tiles were cut
            # (the tile is done, once, with its last part)
            out = []
            parts = np.split(np.arange(tile.rows), gaps)
            for i, rows in enumerate(parts):
                part = slice(int(rows[0]), int(rows[-1]) + 1)
                out.extend(self.push(tile.replace(pixels=tile.pixels[part], ping_time=tile.ping_time[part],
                                                  nav=tile.nav.slice(part)), _counted=i == len(parts) - 1))
            return out
        out: list[StripUnit] = []
        st = self._legs.get(tile.side)
        if st is not None:
            # another leg or range axis ends the strip as a matter of course; a gap or another
            # ping spacing within the leg is counted
            other = st.leg != tile.leg or st.mission != tile.mission or tile.dr_m != st.dr_m
            why = ("" if other else BREAK_GAP if tile.ping_time[0] - st.last_time > self.max_gap_s
                   else BREAK_DX if not abs(tile.dx_m - st.dx_m) <= DX_TOLERANCE * st.dx_m else None)
            if why is not None:
                if why:
                    self.breaks[why] += 1
                out.extend(self.flush(tile.side))
                st = None
        if st is None:
            g = (self.m, None) if self.geometry is None else tuple(self.geometry(tile))
            m, k = g[0], None if g[1] is None else max(int(g[1]), 1)
            k0 = k if len(g) < 3 or g[2] is None or k is None else max(int(g[2]), k)
            st = _LegState(tile.mission, tile.leg, tile.side, tile.range0_m, tile.dr_m, tile.dx_m, tile.kind,
                           tile.cols, tile.seq, -np.inf, int(m), k, _Rows(tile.cols), _Rows(tile.cols), {}, k0)
            self._legs[tile.side] = st
        elif tile.seq <= st.last_seq:
            self.seq_repeats += 1
        sat = tile.saturation
        if sat is not None:
            # the lowest: a tile whose samples never reached the recorder's clip level says
            # only its word's range (Tile.saturation), the others where it clips
            st.full_scale = sat if st.full_scale is None else min(st.full_scale, sat)
        px = self._on_axis(tile, st)
        n, self._next = self._next, self._next + 1
        st.seqs[n] = tile.seq
        if not _counted:
            self._uncounted.add(n)
        st.pending.append(px, tile.ping_time, _nav_array(tile), n)
        st.last_seq, st.last_time = tile.seq, float(tile.ping_time[-1])
        if st.k is None:
            n_core = len(st.pending) - st.m
            if n_core > 0:
                out.append(self._emit(st, n_core, future=st.m))
            return out
        out.extend(self._drain(st, final=False))
        return out

    def flush(self, side: str | None = None) -> list[StripUnit]:
        """End the strip of one side (or both): emit the rows still pending."""
        out = []
        for s in ([side] if side else list(self._legs)):
            st = self._legs.pop(s, None)
            if st is None:
                continue
            if st.k is not None:
                out.extend(self._drain(st, final=True))
            elif len(st.pending):
                out.append(self._emit(st, len(st.pending), future=0))
        return out

    def _drain(self, st: _LegState, *, final: bool) -> list[StripUnit]:
        """Fixed units: emit each unit of ``k`` core rows whose ``m`` following rows are pending
        (the strip's first unit waits for ``k0 + m`` rows, its lookahead, unless the strip
        ends); ``final`` (the strip ends): then the rows left, with no future rows. Depends only
        on the rows pending, never on the tiles that brought them."""
        out: list[StripUnit] = []

        def first() -> bool:
            return st.units == 0 and st.k0 is not None and st.k0 > st.k

        if first() and not final and len(st.pending) < st.k0 + st.m:
            return out
        need = st.k + st.m
        if len(st.pending) >= need:
            pend = st.pending.take(slice(None))  # joined once: the units below are views of it
            start = 0
            while len(pend) - start >= need:
                look = pend.take(slice(start, start + st.k0)).px if first() else None
                st.pending = pend.take(slice(start, start + need))
                out.append(self._emit(st, st.k, future=st.m, rest=pend.take(slice(start + need, None)),
                                      lookahead=look))
                start += st.k
            st.pending = pend.take(slice(start, None))
        if final and len(st.pending):
            out.append(self._emit(st, len(st.pending), future=0))
        return out

    @property
    def margin_rows(self) -> int:
        """The largest margin of the strips open now (``m`` when none is)."""
        return max([st.m for st in self._legs.values()], default=self.m)

    @property
    def pending_rows(self) -> int:
        return sum(len(st.pending) for st in self._legs.values())

    def _on_axis(self, tile: Tile, st: _LegState) -> np.ndarray:
        shift = int(round((tile.range0_m - st.range0_m) / st.dr_m))
        if shift == 0 and tile.cols == st.cols:
            return tile.pixels
        out = np.full((tile.rows, st.cols), np.nan, np.float32)
        lo, hi = max(shift, 0), min(shift + tile.cols, st.cols)
        if hi > lo:
            out[:, lo:hi] = tile.pixels[:, lo - shift:hi - shift]
        return out

    def _emit(self, st: _LegState, n_core: int, future: int, rest: _Rows | None = None,
              lookahead: np.ndarray | None = None) -> StripUnit:
        """A unit of the context, ``n_core`` core rows and ``future`` rows (``st.pending``
        holds just those two); ``rest``: the rows pending after them (the caller keeps them)."""
        ctx, pend = st.context, st.pending
        rows = ctx.cat(pend, self.alloc)
        core = slice(len(ctx), len(ctx) + n_core)
        nav = rows.nav
        core_end = core.stop
        in_core = [int(n) for n in np.unique(rows.src[core])]
        later = set(np.unique(rows.src[core_end:]).tolist())
        if rest is not None and len(rest):
            later |= set(np.unique(rest.src).tolist())
        done = [n for n in in_core if n not in later]
        unit = StripUnit(st.mission, st.leg, st.side, st.last_seq, rows.px, rows.t,
                         TileNav(nav[:, 0].copy(), nav[:, 1].copy(), nav[:, 2].copy(), nav[:, 3].copy()), core,
                         st.range0_m, st.dr_m, st.dx_m, st.kind, tuple(st.seqs.get(n, n) for n in in_core),
                         tuple(st.seqs.get(n, n) for n in done if n not in self._uncounted), lookahead,
                         full_scale=st.full_scale)
        for n in done:  # no row of theirs is pending any more
            st.seqs.pop(n, None)
            self._uncounted.discard(n)
        # the new context: the last m core rows; the new pending: the rows after the core
        # (copies, a margin's rows each: the unit's memory may be reused once it is fused)
        st.context = rows.take(slice(max(core_end - st.m, 0), core_end), copy=True)
        st.pending = rows.take(slice(core_end, None), copy=True)
        assert len(st.pending) == (len(pend) - n_core)
        st.units += 1
        return unit

    # -- snapshot --------------------------------------------------------------------------
    def state(self) -> dict:
        """Plain data for a snapshot."""
        out = {}
        for side, st in self._legs.items():
            out[side] = {k: getattr(st, k) for k in ("mission", "leg", "side", "range0_m", "dr_m", "dx_m", "kind",
                                                      "cols", "last_seq", "last_time", "m", "k", "k0",
                                                      "units", "full_scale")}
            out[side]["seqs"] = [[n, s] for n, s in st.seqs.items()]  # JSON: no int keys
            out[side]["next"] = self._next
            for name in ("context", "pending"):
                r = getattr(st, name)
                out[side][name] = {"px": r.px, "t": r.t, "nav": r.nav, "src": r.src}
        return out

    def restore(self, state: dict) -> None:
        self._legs = {}
        for side, d in state.items():
            rows = {}
            for name in ("context", "pending"):
                px, t, nav, src = (np.asarray(d[name][k]) for k in ("px", "t", "nav", "src"))
                rows[name] = _Rows.of(px.reshape(-1, int(d["cols"])), t, nav.reshape(-1, 4), src)
            # a snapshot older than the arrival numbers holds seqs in src: each its own number
            seqs = {int(n): int(s) for n, s in d.get("seqs", [[int(x), int(x)] for x in np.unique(rows["pending"].src)])}
            self._legs[side] = _LegState(d["mission"], int(d["leg"]), d["side"], float(d["range0_m"]),
                                         float(d["dr_m"]), float(d["dx_m"]), d["kind"], int(d["cols"]),
                                         int(d["last_seq"]), float(d["last_time"]), int(d.get("m", self.m)),
                                         None if d.get("k") is None else int(d["k"]), rows["context"],
                                         rows["pending"], seqs, None if d.get("k0") is None else int(d["k0"]),
                                         int(d.get("units", 1)),
                                         None if d.get("full_scale") is None else float(d["full_scale"]))
            srcs = [int(rows[k].src.max()) + 1 for k in ("context", "pending") if len(rows[k])]
            self._next = max([self._next, int(d.get("next", 0)), *srcs])
