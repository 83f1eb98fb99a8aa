"""Block reader: window sums from the summed-area tables, then the detector formulas (SPEC 2).

For a block of anchor rows at a time (sized to stay in cache), each needed table gives a row
strip over the template rows (and one over the SMF context rows), then box sums per window
with per-column offsets: slices for the echo zone, gathers where the shadow length changes
with range. Counts of valid pixels become reciprocals with NaN where a window is less than
``min_valid_fraction`` valid, so invalid windows flow through the formulas as NaN. When no
data only fills whole columns (nadir gap, past maximum range) the counts are products of rows
and valid columns and no mask table is read at all.
"""

from __future__ import annotations

import numpy as np

from ..config import DetectorSettings
from .formulas import FORMULAS, WindowMeans
from .sat import ColumnPairs, SummedAreaTables, box
from .windows import WindowGeometry

_BLOCK_BYTES = 3 << 17
"""Target size of one row strip (384 kB), so a block's intermediates stay in cache (the L2 of
this machine's cores is 1 MB): best of 256 kB-1 MB on the benchmark tile, 168-173 ms against
185-189 ms for 1 MB (``tools/bench/detectors.py score``, 2026-11-23)."""


def _separable_recips(anchor_rows: np.ndarray, rows_off: tuple[int, int], cols_in: np.ndarray,
                      need: np.ndarray, row_pre: np.ndarray, ftype: type) -> tuple[np.ndarray, np.ndarray]:
    """1 / valid count of a window for every anchor when the valid mask is separable.

    The count is (valid tile rows inside the window) x (valid columns inside it), the rows
    from ``row_pre``, the prefix sums of the valid rows. A tile has few distinct row counts
    (the full window, and one less per ping drop-out or tile edge inside it), so this returns
    one reciprocal row per distinct count, NaN below ``need``, and which row each anchor row
    uses: a block of anchors with one count reads a broadcast row, others one gather
    (:func:`_block_recip`).

    Returns
    -------
    table : ndarray, shape (distinct counts, anchor cols)
    which : ndarray of intp, shape (anchor rows,)
    """
    n_rows = row_pre.size - 1
    rows_in = row_pre[np.clip(anchor_rows + rows_off[1], 0, n_rows)] - row_pre[np.clip(anchor_rows + rows_off[0], 0, n_rows)]
    counts, which = np.unique(rows_in, return_inverse=True)
    n = counts[:, None] * cols_in[None, :]
    table = np.divide(1.0, n, dtype=ftype)
    np.copyto(table, np.nan, where=n < need)
    return table, which.reshape(-1).astype(np.intp)


def _block_recip(table: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Reciprocal counts of a block of anchor rows from :func:`_separable_recips`' table."""
    first = int(which[0])
    if which.size == 1 or (which == first).all():
        return table[first:first + 1]
    return table.take(which, axis=0)


def _separable_setup(geom: WindowGeometry, js: np.ndarray, needs: set[str], col_valid: np.ndarray,
                     median_n: np.ndarray | None, ftype: type
                     ) -> tuple[set[str], dict[str, np.ndarray], dict[str, tuple[str, np.ndarray]]]:
    """Per-anchor-column counts and matched-filter offsets for a separable valid mask.

    Returns the sums still to read from tables, the valid columns inside each window
    (anchor cols,), and the derived matched-filter means:
    mean(J, w) = mean(p, w) + 1 - (mean of median_n over the valid columns of w).
    """
    cols = col_valid.size

    def inside(values: np.ndarray, off0: np.ndarray | int, off1: np.ndarray | int) -> np.ndarray:
        """Sum of per-column ``values`` over each anchor's columns [j + off0, j + off1), clipped."""
        pre = np.concatenate([[0], np.cumsum(values)])
        o0 = off0 if np.isscalar(off0) else np.asarray(off0)[js]
        o1 = off1 if np.isscalar(off1) else np.asarray(off1)[js]
        return pre[np.clip(js + o1, 0, cols)] - pre[np.clip(js + o0, 0, cols)]

    spans = {"E": (-geom.echo_px, 0), "S": (0, geom.shadow_px), "C": (geom.ctx_col0, geom.ctx_col1)}
    cols_in = {w: inside(col_valid.astype(np.int64), *o) for w, o in spans.items()}
    needs = needs - {"n_E", "n_S", "n_C"}
    derived: dict[str, tuple[str, np.ndarray]] = {}
    if median_n is not None and needs & {"j_E", "j_S"}:
        needs = (needs - {"j_E", "j_S"}) | {"p_E", "p_S"}
        med_valid = np.where(col_valid, median_n, 0.0)
        for w in ("E", "S"):
            offset = 1.0 - inside(med_valid, *spans[w]) / cols_in[w]
            derived[f"j_{w}"] = ("p", offset.astype(ftype)[None, :])
    return needs, cols_in, derived


@np.errstate(invalid="ignore", divide="ignore", over="ignore")  # NaN windows flow through as NaN
def read_scores(sat: SummedAreaTables, geom: WindowGeometry, names: tuple[str, ...], needs: set[str],
                 first_row: int, n_out: int, detectors: DetectorSettings, ftype: type,
                 col_valid: np.ndarray | None = None,
                 median_n: np.ndarray | None = None, row_valid: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Read the window sums block by block and apply the formulas (SPEC 2).

    ``col_valid`` (cols,) and ``row_valid`` (rows,; None = every row) mark a separable valid
    mask: counts are then products of valid rows and valid columns inside each window, with
    no mask table. With it, ``median_n`` (cols,), the
    per-column median of I_n, gives the matched filter's means from those of I_n.
    """
    step = detectors.decimation
    cols = sat.cols
    anchors = slice(0, cols, step)
    js = np.arange(cols)[anchors]
    # Column selectors: echo [j - W, j) and shadow start are slices, the rest gathers.
    e0, e1 = sat.columns(-geom.echo_px, anchors), sat.columns(0, anchors)
    s1 = sat.columns(geom.shadow_px, anchors)
    c0, c1 = sat.columns(geom.ctx_col0, anchors), sat.columns(geom.ctx_col1, anchors)
    # Slices where the offsets stay constant over long runs of anchors, gathers elsewhere.
    pairs = {"E": ColumnPairs(e0, e1, step), "S": ColumnPairs(e1, s1, step), "C": ColumnPairs(c0, c1, step)}
    area = {"E": np.int32(geom.length_px * geom.echo_px),
            "S": (geom.length_px * geom.shadow_px[js]).astype(np.int32),
            "C": ((geom.ctx_row1 - geom.ctx_row0) * (geom.ctx_col1 - geom.ctx_col0)[js]).astype(np.int32)}
    # An integer count n is at least frac * area exactly when n >= ceil(frac * area). The echo
    # and shadow zones need more of their pixels (min_valid_fraction_zones): half an echo zone
    # at a no-data edge (the first-return band, the swath's end) measures the edge, not a target.
    zones = max(detectors.min_valid_fraction_zones, detectors.min_valid_fraction)
    frac = {"E": zones, "S": zones, "C": detectors.min_valid_fraction}
    need = {w: np.ceil(frac[w] * a - 1e-9).astype(np.int32) for w, a in area.items()}
    rows_dec = -(-n_out // step)
    # The maps live in the workspace (no page faults on fresh memory from tile to tile): with a
    # caller's workspace they are valid until its next call.
    out = {d: sat.ws.array("out " + d, (rows_dec, js.size), ftype) for d in names}
    block = max(1, _BLOCK_BYTES // (8 * (sat.cols + sat.pad.left + sat.pad.right + 1)))
    t_rows = (geom.row0, geom.row1)
    c_rows = (geom.ctx_row0, geom.ctx_row1)
    windows = sorted({k[-1] for k in needs if k.startswith("n_")})
    rows_off = {"E": t_rows, "S": t_rows, "C": c_rows}
    derived: dict[str, tuple[str, np.ndarray]] = {}
    if col_valid is not None:
        needs, cols_in, derived = _separable_setup(geom, js, needs, col_valid, median_n, ftype)
        rv = np.ones(sat.rows, dtype=np.int64) if row_valid is None else row_valid.astype(np.int64)
        row_pre = np.concatenate([[0], np.cumsum(rv)])
        anchors_all = first_row + np.arange(rows_dec) * step
        recips = {w: _separable_recips(anchors_all, rows_off[w], cols_in[w], need[w], row_pre, ftype)
                  for w in windows}

    for k0 in range(0, rows_dec, block):
        count = min(block, rows_dec - k0)
        i0 = first_row + k0 * step
        s: dict[str, np.ndarray] = {}
        for table, wanted in (("n", ("E", "S")), ("p", ("E", "S")), ("p2", ("S",)),
                              ("j", ("E", "S")), ("g", ("E", "S"))):
            keys = [w for w in wanted if f"{table}_{w}" in needs]
            if not keys:
                continue
            d = sat.strip(table, i0, count, step, *t_rows)
            for w in keys:
                s[f"{table}_{w}"] = box(d, pairs[w])
                if table == "g":
                    # Codes are 2S + 2 over the whole window (pad and no data hold 2).
                    s[f"g_{w}"] -= 2 * area[w]
        for table in ("n", "ag"):
            if f"{table}_C" in needs:
                s[f"{table}_C"] = box(sat.strip(table, i0, count, step, *c_rows), pairs["C"])
        recip = {}
        if col_valid is not None:
            for w in windows:
                table, which = recips[w]
                recip[w] = _block_recip(table, which[k0:k0 + count])
        for w in ("E", "S", "C"):
            if f"n_{w}" in s:
                n = s.pop(f"n_{w}")
                # 1 / count, NaN where the window is less than min_valid_fraction valid (SPEC 2).
                r = np.divide(1.0, n, dtype=ftype)
                np.copyto(r, np.nan, where=n < need[w])
                recip[w] = r
        means = WindowMeans(s, recip, derived)
        for d in names:
            FORMULAS[d](means, detectors, out=out[d][k0:k0 + count])
    if step > 1:
        out = {d: np.repeat(np.repeat(g, step, axis=0)[:n_out], step, axis=1)[:, :cols]
               for d, g in out.items()}
    return out
