"""Joining a leg's tiles into a strip, so that core scores do not depend on tile cuts.

SPEC section 0: detectors see a margin of at least half the largest window around each tile
core, and evidence is deposited from the core only. Tiles span the whole swath in range, so
cuts are along-track (rows) only. For a margin of ``m`` rows, each tile that arrives
finalises a core shifted back by ``m`` rows: the rows whose ``m`` following rows are known::

    context (m rows, already emitted) | core (emitted now) | future (m rows, emitted next time)

At the end of a leg (another leg on this side, a gap in ping time, or the end of the input)
the rows still pending are emitted with no future rows, as the whole strip would score them.
The latency this adds is ``m`` pings, not a tile.

Units carry the ping times and per-ping nav of every row, and the column axis of the leg:
later tiles are put on the first tile's axis (same spacing; shifted and NaN-padded by whole
columns).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import TileError
from ..records.tile import Tile, TileNav


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

    @property
    def core_rows(self) -> int:
        return self.core.stop - self.core.start

    def core_tile(self) -> Tile:
        """The core as a ground-range tile (for georeferencing)."""
        return Tile(self.mission, self.leg, self.side, self.seq, self.pixels[self.core], self.kind, self.range0_m,
                    self.dr_m, self.dx_m, False, self.ping_time[self.core], nav=self.nav.slice(self.core))


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
    context: _Rows
    pending: _Rows
    seqs: dict[int, int]
    """Arrival number -> seq of the tiles with rows in ``pending`` (``src`` holds the number)."""


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
        A gap in ping time larger than this starts a new strip (no context across it).
    """

    def __init__(self, margin_rows: int, *, max_gap_s: float = 5.0,
                 alloc: Callable[[tuple[int, int]], np.ndarray] | None = None) -> None:
        self.m = int(margin_rows)
        self.max_gap_s = float(max_gap_s)
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

    def push(self, tile: Tile) -> list[StripUnit]:
        """Take a ground-range tile with nav; return the units it completes (0, 1 or 2)."""
        if tile.slant or tile.nav is None:
            raise TileError("the strip needs ground range and per-ping nav", tile=tile.ident)
        out: list[StripUnit] = []
        st = self._legs.get(tile.side)
        if st is not None and (st.leg != tile.leg or st.mission != tile.mission
                               or tile.ping_time[0] - st.last_time > self.max_gap_s
                               or tile.dr_m != st.dr_m):
            out.extend(self.flush(tile.side))
            st = None
        if st is None:
            st = _LegState(tile.mission, tile.leg, tile.side, tile.range0_m, tile.dr_m, tile.dx_m, tile.kind,
                           tile.cols, tile.seq, -np.inf, _Rows(tile.cols), _Rows(tile.cols), {})
            self._legs[tile.side] = st
        elif tile.seq <= st.last_seq:
            self.seq_repeats += 1
        px = self._on_axis(tile, st)
        n, self._next = self._next, self._next + 1
        st.seqs[n] = tile.seq
        st.pending.append(px, tile.ping_time, _nav_array(tile), n)
        st.last_seq, st.last_time = tile.seq, float(tile.ping_time[-1])
        n_core = len(st.pending) - self.m
        if n_core > 0:
            out.append(self._emit(st, n_core, future=self.m))
        return out

    def flush(self, side: str | None = None) -> list[StripUnit]:
        """End the strip of one side (or both): emit the rows still pending."""
        out = []
        for s in ([side] if side else list(self._legs)):
            st = self._legs.pop(s, None)
            if st is not None and len(st.pending):
                out.append(self._emit(st, len(st.pending), future=0))
        return out

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

    def _emit(self, st: _LegState, n_core: int, future: int) -> StripUnit:
        ctx, pend = st.context, st.pending
        rows = ctx.cat(pend, self.alloc)
        core = slice(len(ctx), len(ctx) + n_core)
        nav = rows.nav
        core_end = core.stop
        in_core = [int(n) for n in np.unique(rows.src[core])]
        later = set(np.unique(rows.src[core_end:]).tolist())
        done = [n for n in in_core if n not in later]
        unit = StripUnit(st.mission, st.leg, st.side, st.last_seq, rows.px, rows.t,
                         TileNav(nav[:, 0].copy(), nav[:, 1].copy(), nav[:, 2].copy(), nav[:, 3].copy()), core,
                         st.range0_m, st.dr_m, st.dx_m, st.kind, tuple(st.seqs.get(n, n) for n in in_core),
                         tuple(st.seqs.get(n, n) for n in done))
        for n in done:  # no row of theirs is pending any more
            st.seqs.pop(n, None)
        # the new context: the last m core rows; the new pending: the rows after the core
        # (copies, a margin's rows each: the unit's memory may be reused once it is fused)
        st.context = rows.take(slice(max(core_end - self.m, 0), core_end), copy=True)
        st.pending = rows.take(slice(core_end, None), copy=True)
        assert len(st.pending) == (len(pend) - n_core)
        return unit

    # -- snapshot --------------------------------------------------------------------------
    def state(self) -> dict:
        """Plain data for a snapshot."""
        out = {}
        for side, st in self._legs.items():
            out[side] = {k: getattr(st, k) for k in ("mission", "leg", "side", "range0_m", "dr_m", "dx_m", "kind",
                                                      "cols", "last_seq", "last_time")}
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
                                         int(d["last_seq"]), float(d["last_time"]), rows["context"], rows["pending"],
                                         seqs)
            srcs = [int(rows[k].src.max()) + 1 for k in ("context", "pending") if len(rows[k])]
            self._next = max([self._next, int(d.get("next", 0)), *srcs])
