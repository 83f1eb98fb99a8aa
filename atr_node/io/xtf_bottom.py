"""Sonar altitude from the first bottom return of slant-range pings (bottom tracking).

Side-scan recordings carry the altitude of a separate altimeter (a DVL beam, an echo sounder),
mounted elsewhere on the vehicle and sometimes pointing through a pitched hull, or no altitude
at all (0 in every ping of some exports). Slant-to-ground conversion (SPEC section 0,
``r = sqrt(R^2 - H^2)``) needs the altitude of the side-scan transducers themselves: when the
altitude used is short by dH, the water column lands on the ground axis as a dark band of
width about ``sqrt(2 H dH)`` next to the nadir, which looks like a shadow to the detectors.
The first bottom return in the pings measures that altitude directly.

What the real pings show (``docs/xtf.md``): a bright ring-down of the transmitter over the
first 0.2-0.4 m, then the dark water column (with, in some files, stationary bright lines a few
samples wide at fixed ranges, fish, or surface arcs), then the first bottom return: a step up
by a factor 10-100 to the seabed level, which then stays bright. So, per ping and side:

1. ``L`` = log amplitude, median-filtered along range over ``window_m`` (at least 7 samples):
   thin lines (cross-talk, fish, speckle spikes) vanish, the step to the seabed stays sharp.
2. The ringing zone ends where the median over the pings of ``L`` first falls back to the water
   column after its peak near sample 0 (measured on the pings themselves, so no sensor
   constant is needed); no return is looked for before it.
3. Step score at range R: mean of ``L`` over ``window_m`` after R minus the mean before it (a
   rise by a factor e^score), less ``bright_penalty`` per metre of seabed-bright samples
   already seen before R: the first return has only water before it; the far edge of a shadow,
   an equally strong rise, has seabed before it.

Both sides' scores are added (the first return is at the same slant range on both sides of a
level vehicle over a flat seabed), and a dynamic programme over the pings (Viterbi with an L1
penalty of ``jump_penalty`` per metre of altitude change from ping to ping) picks the
continuous track of highest total score: a fish or a patch of noise does not pull the track
away for one ping.

A proud object or a ridge near the nadir (the river file's sand-wave crests: port and
starboard pings 150-160, 232-248, 283-297, 355-378) returns before the seabed over 5-20 pings
(up to 3.4 s), on one side or both, with a shadow behind it; it is as strong a rise as the
seabed, so the Viterbi follows its top and the altitude dips by up to 1 m. The seabed is the
continuous, later return: a grey closing along track over ``envelope_s`` (4 s; a dilation,
then an erosion, of the Viterbi track) fills every dip shorter than that and leaves any
monotonic change of altitude (a descent, a climb, a bank) and any dip or rise longer than it
untouched. Such an object lies above the seabed (R < H): the flat-seabed geometry cannot place
it, and it lands in the water column, which the node drops. Across blocks the closing continues
over the previous block's raw track (``prior``); a dip still under way at a block's last ping
is kept (the future is not read). A ping's track is ``found`` when the score at the final range
shows a rise by at least ``min_rise`` on at least one side.

Cost: the first return lies in the near part of the swath, so a block that follows another is
filtered and scored only up to :func:`search_limit_m` (twice the previous block's highest
altitude + 5 m) and the seabed levels come from a column subsample; when the track reaches that
limit or finds no rise before it, the block is tracked again over the whole swath. Port and
starboard on different range axes are tracked on the finer one (the other resampled).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from ..records.tile import Tile

__all__ = ["BottomTrack", "bottom_altitude_m", "first_return_length_m", "first_return_m", "ringing_end_m",
           "search_limit_m", "shares_axis", "track_bottom"]


@dataclass(frozen=True)
class BottomTrack:
    """Result of :func:`track_bottom`, one value per ping."""

    altitude_m: np.ndarray
    """(rows,) float64 slant range of the first bottom return; NaN when no ping of the block
    shows one (the track is continuous: pings in between are carried from their neighbours)."""
    found: np.ndarray
    """(rows,) bool: the tracked range is a clear rise (>= ``min_rise``) on at least one side."""
    ringing_end_m: float
    """Slant range where the transmit ringing ends (the shortest altitude looked for)."""
    raw_m: np.ndarray | None = None
    """(rows,) the Viterbi track before the along-track envelope (what the next block continues)."""


def _window(tile: Tile, window_m: float) -> int:
    # at least 7 samples, so that lines up to 3 samples wide vanish in the median
    k = max(int(round(window_m / tile.dr_m)), 7)
    return k | 1


def ringing_end_m(tile: Tile, *, window_m: float = 0.3) -> float:
    """Slant range where the transmit ringing of a slant tile ends, measured on its pings.

    The median over the pings of the log amplitude peaks within the first samples (the
    ring-down) and falls to the water column; the ringing ends at the first sample after the
    peak within a factor 2 of the darkest column (the water column, or the seabed's darkest
    part if the vehicle flies lower than the ringing lasts, which a first return cannot be).
    """
    if not tile.slant:
        raise ValueError(f"{tile.ident}: bottom tracking needs slant-range pings")
    return _ring_end(tile.pixels, tile.range0_m, tile.dr_m, tile.cols, 1)


def shares_axis(a: Tile, b: Tile) -> bool:
    """True when two tiles have the same range axis (columns, spacing and first range to 1e-4)."""
    return a.cols == b.cols and bool(np.isclose(a.dr_m, b.dr_m, rtol=1e-4)) \
        and bool(np.isclose(a.range0_m, b.range0_m, rtol=1e-4, atol=1e-4 * b.dr_m))


def _onto_axis(tile: Tile, ref: Tile) -> np.ndarray:
    """``tile``'s pixels (no data 0) linearly interpolated at ``ref``'s ranges; past either end
    of ``tile``'s own axis its edge sample (flat: no rise is made there)."""
    px = np.nan_to_num(tile.pixels.astype(np.float64), nan=0.0)
    f = np.clip((ref.range0_m + ref.dr_m * np.arange(ref.cols) - tile.range0_m) / tile.dr_m, 0.0, tile.cols - 1)
    i0 = np.floor(f).astype(np.int64)
    i1 = np.minimum(i0 + 1, tile.cols - 1)
    w = f - i0
    return px[:, i0] * (1.0 - w) + px[:, i1] * w


def _log1p(px: np.ndarray) -> np.ndarray:
    # log(1 + a): rises are ratios; the +1 keeps no-data (0) and 8-bit water (5) finite
    return np.log1p(np.maximum(np.nan_to_num(np.asarray(px, dtype=np.float64), nan=0.0), 0.0))


def _median_at(px: np.ndarray, centres: np.ndarray, k: int) -> np.ndarray:
    """(rows, centres) median of the log amplitude over ``k`` samples around each centre: the
    values ``ndi.median_filter(size=(1, k), mode="nearest")`` has there, for those columns only."""
    h = k // 2
    idx = np.clip(centres[:, None] + np.arange(-h, h + 1)[None, :], 0, px.shape[1] - 1)
    return np.median(_log1p(px[:, idx]), axis=2)


class _NeedFullWidth(Exception):
    """The near columns do not decide the track: it is computed over the full width."""


def _ring_end(px: np.ndarray, r0_m: float, dr_m: float, near: int, step: int) -> float:
    """:func:`ringing_end_m` on the first ``near`` columns exactly and every ``step``-th beyond
    (the darkest column is the water column, in the near part unless the seabed far out is
    darker still)."""
    cols = px.shape[1]
    col = np.median(_log1p(px[:, :near]), axis=0)
    far = np.arange(near, cols, step)
    far_col = np.median(_log1p(px[:, far]), axis=0) if far.size else np.zeros(0)
    head = max(cols // 8, 2)
    peak = int(np.argmax(col[:head]))
    water = float(min(np.min(col[peak:]), np.min(far_col) if far.size else np.inf))
    dark = np.flatnonzero(col[peak:] <= water + np.log(2.0))
    if not dark.size:
        if far.size:
            raise _NeedFullWidth
        return float(r0_m + dr_m * peak)
    return float(r0_m + dr_m * (peak + int(dark[0])))


def _side_scores(px: np.ndarray, r0_m: float, dr_m: float, k: int, ring_end_m: float, bright_penalty: float,
                 near: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """(raw rise, penalised score), both (rows, near): at column i, the step from [i-k, i) to
    [i, i+k). Exact for the columns ``i <= near - k - k // 2 - 1``; the seabed levels come from
    every ``step``-th column of the whole width."""
    rows, cols = px.shape
    L = ndi.median_filter(_log1p(px[:, :near]), size=(1, k), mode="nearest")
    c = np.concatenate([np.zeros((rows, 1)), np.cumsum(L, axis=1)], axis=1)
    rise = np.full((rows, near), -np.inf)
    i = np.arange(k, near - k + 1)
    rise[:, i] = (c[:, i + k] - c[:, i]) / k - (c[:, i] - c[:, i - k]) / k
    # seabed-bright: above the midpoint (in log) between the ping's water and seabed levels
    start = min(max(int(np.ceil((ring_end_m - r0_m) / dr_m)), 0), cols - 1)
    if near == cols:
        tail = L[:, start:]
    else:  # the levels of the whole swath from a column subsample (the median filter costs)
        tail = _median_at(px, np.arange(start, cols, step), k)
    lo = np.percentile(tail, 10, axis=1)
    hi = np.percentile(tail, 75, axis=1)
    bright = (L > 0.5 * (lo + hi)[:, None]) & ((hi - lo) > np.log(4.0))[:, None]
    bright[:, :start] = False
    # bright samples strictly before the window that precedes i (the edge itself is allowed)
    seen = np.concatenate([np.zeros((rows, 1)), np.cumsum(bright, axis=1)], axis=1)
    before = seen[:, np.clip(np.arange(near) - k, 0, near)]
    score = np.clip(rise, 0.0, None) - bright_penalty * dr_m * before
    return rise, score


NEAR_FACTOR = 2.0
NEAR_MARGIN_M = 5.0
"""Default search limit of a block that follows another: ``NEAR_FACTOR`` x the previous block's
highest altitude + ``NEAR_MARGIN_M`` (the first return lies in the near part of the swath)."""
SEABED_COLUMNS = 256
"""About this many columns (a subsample) give the seabed levels of the bright penalty."""


def search_limit_m(prior: BottomTrack | None, prior_m: float | None = None) -> float:
    """Slant range beyond which :func:`track_bottom` looks for no first return by default:
    ``NEAR_FACTOR`` x the highest altitude of the previous block's raw track (or ``prior_m``)
    + ``NEAR_MARGIN_M``; infinite (the whole swath) without a previous block."""
    hist = [float(prior_m)] if prior_m is not None and np.isfinite(prior_m) else []
    if prior is not None and prior.raw_m is not None and np.isfinite(prior.raw_m).any():
        hist.append(float(np.nanmax(prior.raw_m)))
    return NEAR_FACTOR * max(hist) + NEAR_MARGIN_M if hist else np.inf


def track_bottom(port: Tile | None, stbd: Tile | None, *, prior_m: float | None = None,
                 prior: BottomTrack | None = None, window_m: float = 0.3, jump_penalty: float = 2.0,
                 bright_penalty: float = 2.0, min_rise: float = np.log(3.0), min_altitude_m: float = 0.0,
                 envelope_s: float = 4.0, min_dip_m: float = 0.2, max_altitude_m: float | None = None,
                 seabed_columns: int | None = SEABED_COLUMNS) -> BottomTrack:
    """First bottom return per ping from one or both sides of a block of slant pings.

    Parameters
    ----------
    port, stbd
        Slant-range tiles of the same pings (columns from the nadir outwards); either may be
        None. When both are given with different range axes (sample count, spacing or first
        range), the coarser side is linearly resampled onto the finer side's axis (port's on a
        tie), past its own range end by its last sample.
    prior_m
        The altitude just before this block (the end of the previous block's track): the
        track starts near it at the same ``jump_penalty``, so blocks join continuously.
    prior
        The previous block's result: its last raw altitude is ``prior_m`` (unless given) and
        its raw track is the history of the along-track envelope, so a dip that began in the
        previous block is filled here too.
    window_m
        Length over which the rise is measured (and of the median filter), at least 7 samples.
    jump_penalty
        Cost per metre of altitude change between consecutive pings, in units of the log rise
        (a rise by e on both sides scores 2): 2 means a one-ping excursion of 1 m and back
        needs a rise by e^4 more than the continuous track offers.
    bright_penalty
        Cost per metre of seabed-bright samples before a candidate.
    min_rise
        Natural log of the rise that makes a ping's track ``found`` (default a factor 3).
    min_altitude_m
        No return is looked for before this range, nor before the ringing's end.
    envelope_s
        Length (seconds of pings, from the tiles' ``ping_time``) of the along-track grey
        closing: early returns shorter than this are filled to the seabed's later return
        (module docstring); 0 turns it off.
    min_dip_m
        Only dips that the closing raises by more than this somewhere are filled (the whole
        dip then): the bottom of a smooth real valley of the vehicle's altitude (2.5 to 5.5 m
        and back over 30 s: 0.1 m under a 4 s closing) and one-sample jitter stay as tracked.
    max_altitude_m
        No return is looked for beyond this slant range, and only the columns up to it (plus
        the windows) are filtered and scored: the first return lies in the near part of the
        swath. None: :func:`search_limit_m` of ``prior`` (the whole swath without one); inf:
        the whole swath. When the track comes within two windows of the limit, or shows no
        clear rise before it, the block is tracked again over the whole swath.
    seabed_columns
        The per-ping seabed levels (the bright penalty's threshold) are taken from about this
        many columns spread over the swath instead of every column; None: every column.

    Returns
    -------
    BottomTrack
    """
    tiles = [t for t in (port, stbd) if t is not None]
    if not tiles:
        raise ValueError("bottom tracking needs at least one side")
    for t in tiles:
        if not t.slant:
            raise ValueError(f"{t.ident}: bottom tracking needs slant-range pings")
        if t.rows != tiles[0].rows:
            raise ValueError(f"{t.ident}: both sides must hold the same pings")
    # the finest axis (port's on a tie) is the one the track is searched on
    ref = min(tiles, key=lambda t: t.dr_m)
    pxs = [t.pixels if shares_axis(t, ref) else _onto_axis(t, ref) for t in tiles]
    if max_altitude_m is None:
        max_altitude_m = search_limit_m(prior, prior_m)
    limit_m = float(max_altitude_m)
    try:
        return _track(pxs, ref, limit_m, prior_m=prior_m, prior=prior, window_m=window_m,
                      jump_penalty=jump_penalty, bright_penalty=bright_penalty, min_rise=min_rise,
                      min_altitude_m=min_altitude_m, envelope_s=envelope_s, min_dip_m=min_dip_m,
                      seabed_columns=seabed_columns)
    except _NeedFullWidth:
        return _track(pxs, ref, np.inf, prior_m=prior_m, prior=prior, window_m=window_m,
                      jump_penalty=jump_penalty, bright_penalty=bright_penalty, min_rise=min_rise,
                      min_altitude_m=min_altitude_m, envelope_s=envelope_s, min_dip_m=min_dip_m,
                      seabed_columns=seabed_columns)


def _track(pxs: list[np.ndarray], t0: Tile, limit_m: float, *, prior_m: float | None, prior: BottomTrack | None,
           window_m: float, jump_penalty: float, bright_penalty: float, min_rise: float, min_altitude_m: float,
           envelope_s: float, min_dip_m: float, seabed_columns: int | None) -> BottomTrack:
    """:func:`track_bottom` on pixel arrays sharing ``t0``'s axis, searched up to ``limit_m``;
    raises :class:`_NeedFullWidth` when that limit may have decided the track."""
    rows, cols = t0.rows, t0.cols
    r0, dr = t0.range0_m, t0.dr_m
    k = _window(t0, window_m)
    cropped = np.isfinite(limit_m)
    last = int(np.floor((limit_m - r0) / dr)) if cropped else cols - 1
    if last >= cols - 1:
        cropped, last = False, cols - 1
    step = 1
    if seabed_columns is not None and seabed_columns > 0:
        step = max((cols - 1) // int(seabed_columns), 1)
    # columns filtered: the search range, its windows and the median's half width (exact there);
    # with every column wanted for the seabed levels anyway, all of them
    near = cols if not cropped or step == 1 else min(cols, max(last + k + k // 2 + 2, max(cols // 8, 2)))
    ring_m = max(_ring_end(px, r0, dr, near, step) for px in pxs)
    lo_m = max(ring_m, float(min_altitude_m))
    rises, total = [], np.zeros((rows, near))
    for px in pxs:
        rise, score = _side_scores(px, r0, dr, k, lo_m, bright_penalty, near, step)
        rises.append(rise)
        total += score
    ranges = r0 + dr * np.arange(near)
    states = np.flatnonzero((ranges >= lo_m) & (np.arange(near) <= last) & np.isfinite(total).all(axis=0))
    nan = np.full(rows, np.nan)
    if states.size == 0:
        if cropped:
            raise _NeedFullWidth
        return BottomTrack(nan, np.zeros(rows, bool), ring_m, nan)
    cost = -total[:, states]  # (rows, n)
    strong = np.max(np.stack([r[:, states] for r in rises]), axis=0) >= min_rise
    if not strong.any():
        if cropped:
            raise _NeedFullWidth
        return BottomTrack(nan, np.zeros(rows, bool), ring_m, nan)
    # Viterbi with an L1 transition cost: min_j D[j] + lam |i - j| in O(n) by two running minima
    lam = jump_penalty * dr
    idx = np.arange(states.size, dtype=np.float64)
    acc = np.empty_like(cost)
    d = cost[0].copy()
    if prior_m is None and prior is not None and prior.raw_m is not None and np.isfinite(prior.raw_m).any():
        prior_m = float(prior.raw_m[np.isfinite(prior.raw_m)][-1])
    if prior_m is not None and np.isfinite(prior_m):
        d += jump_penalty * np.abs(ranges[states] - prior_m)
    acc[0] = d
    for r in range(1, rows):
        fwd = np.minimum.accumulate(d - lam * idx) + lam * idx
        bwd = np.minimum.accumulate((d + lam * idx)[::-1])[::-1] - lam * idx
        d = np.minimum(fwd, bwd) + cost[r]
        acc[r] = d
    path = np.empty(rows, dtype=np.int64)
    path[-1] = int(np.argmin(acc[-1]))
    for r in range(rows - 2, -1, -1):
        path[r] = int(np.argmin(acc[r] + lam * np.abs(idx - path[r + 1])))
    if cropped and states[path].max() > last - 2 * k:
        raise _NeedFullWidth  # the track reaches the limit: what lies beyond it may be the seabed
    raw = ranges[states[path]].astype(np.float64)
    history = prior.raw_m if prior is not None and prior.raw_m is not None else None
    w = _envelope_pings(t0.ping_time, envelope_s)
    if w > 1:
        # the closing returns values of the track itself, so every ping stays on a state
        path = np.clip(np.searchsorted(ranges[states], _close_dips(raw, w, history, min_dip_m)
                                       - 0.5 * dr), 0, states.size - 1)
    found = strong[np.arange(rows), path]
    return BottomTrack(ranges[states[path]].astype(np.float64), found, ring_m, raw)


def _envelope_pings(ping_time: np.ndarray, envelope_s: float) -> int:
    """``envelope_s`` in pings (odd), from the median ping interval; 1 = no envelope."""
    if not envelope_s > 0 or ping_time.size < 2:
        return 1
    dt = float(np.median(np.diff(np.asarray(ping_time, dtype=np.float64))))
    if not (np.isfinite(dt) and dt > 0):
        return 1
    return int(round(envelope_s / dt)) | 1


def _close_dips(track_m: np.ndarray, w: int, history_m: np.ndarray | None, min_dip_m: float = 0.0) -> np.ndarray:
    """Grey closing of ``track_m`` over ``w`` pings: dips shorter than ``w`` are filled, those
    that it raises by more than ``min_dip_m`` somewhere (each run of raised pings as a whole).

    The pings before the block (``history_m``, up to ``w - 1`` of them) extend it at the start;
    beyond them, and at the end, the first/last value is repeated over ``w - 1`` pings, which
    leaves a monotonic track unchanged (no lag, no bias on a real change of altitude) and keeps
    a dip still under way at the end. (``mode="nearest"`` of scipy would repeat the edge of the
    dilated track instead, which holds a descent at its value half a window earlier.)
    """
    pad = w - 1  # the erosion reads the dilation half a window on, which reads half a window on
    head = np.zeros(0)
    if history_m is not None:
        head = np.asarray(history_m, dtype=np.float64)
        head = head[np.isfinite(head)][-pad:]
    x = np.concatenate([np.full(pad - head.size, (head[0] if head.size else track_m[0])), head, track_m,
                        np.full(pad, track_m[-1])])
    closed = ndi.grey_closing(x, size=w, mode="nearest")[pad:pad + track_m.size]
    raised = closed - track_m
    runs, n = ndi.label(raised > 0)
    if n == 0:
        return closed
    deep = np.concatenate([[False], np.asarray(ndi.maximum(raised, runs, np.arange(1, n + 1))) > min_dip_m])
    return np.where(deep[runs], closed, track_m)


def first_return_m(tile: Tile, **kwargs) -> np.ndarray:
    """Slant range of the first bottom return of each ping of one slant-range tile.

    Returns
    -------
    np.ndarray
        (rows,) float64 metres; NaN where the ping shows no clear rise (see :func:`track_bottom`).
    """
    track = track_bottom(None, tile, **kwargs)
    return np.where(track.found, track.altitude_m, np.nan)


def bottom_altitude_m(port: Tile | None, stbd: Tile | None, **kwargs) -> np.ndarray:
    """Sonar altitude per ping from both sides (:func:`track_bottom`); NaN where not found."""
    track = track_bottom(port, stbd, **kwargs)
    return np.where(track.found, track.altitude_m, np.nan)


def first_return_length_m(tile: Tile, altitude_m: np.ndarray, *, level: float = 0.7, max_m: float = 2.5,
                          plateau_m: float = 1.0, min_rows: int = 16) -> float:
    """Slant length of the first bottom return's rise to the seabed's level, measured on a tile.

    Right after the first return (R = H) the seabed is not at once as bright as beyond it: the
    Iver2 file's return climbs from 0.07 to 0.7 of the seabed level over 0.6-1.8 m of slant
    range (the vertical beam pattern: near the nadir the transducers look away from the
    seabed), the river file's port side over 0.1-0.8 m, its starboard side in one sample. On
    the ground axis that ramp is a dark strip next to the nadir; the per-range background b(j)
    cannot normalise it when the altitude changes along the tile (it moves across columns), so
    its far edge looks like a shadow's to the detectors.

    Per tile: every ping's pixels at ``R - H = x`` (nearest sample), the median over the pings
    at each ``x``; the seabed level is that profile's median over ``[max_m, max_m + plateau_m]``;
    the length is the first ``x >= 0`` where the profile reaches ``level`` times it.

    Parameters
    ----------
    tile
        A slant-range tile.
    altitude_m
        (rows,) the altitude used for its pings (the first bottom return).
    level
        Fraction of the seabed level that ends the rise.
    max_m
        Longest length reported (also where the seabed level is measured from).
    plateau_m
        Slant extent of the seabed-level window.
    min_rows
        Fewer pings with data than this: NaN (not measured).

    Returns
    -------
    float
        Metres of slant range in ``[0, max_m]``; NaN when the tile has too few pings with data
        there, or no seabed level (all no data or zero).
    """
    if not tile.slant:
        raise ValueError(f"{tile.ident}: the first return's length needs slant-range pings")
    alt = np.broadcast_to(np.asarray(altitude_m, dtype=np.float64), (tile.rows,))
    xs = np.arange(0.0, max_m + plateau_m + 0.5 * tile.dr_m, tile.dr_m)
    col = np.rint((alt[:, None] + xs[None, :] - tile.range0_m) / tile.dr_m)
    inside = np.isfinite(col) & (col >= 0) & (col <= tile.cols - 1)
    idx = np.where(inside, col, 0).astype(np.int64)
    px = np.take_along_axis(tile.pixels.astype(np.float64), idx, axis=1)
    px[~inside] = np.nan
    if int(np.isfinite(px).all(axis=1).sum()) < min_rows:
        return float("nan")
    prof = np.nanmedian(px, axis=0)
    seabed = float(np.nanmedian(prof[xs >= max_m - 1e-9]))
    if not (np.isfinite(seabed) and seabed > 0):
        return float("nan")
    up = np.flatnonzero(prof >= level * seabed)
    return float(min(xs[up[0]], max_m)) if up.size else float(max_m)
