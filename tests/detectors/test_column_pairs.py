"""Box differences read as slices where a window's offset stays constant, gathers elsewhere."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.detectors.sat import ColumnPairs, box


def _offsets(rng: np.random.Generator, n: int) -> np.ndarray:
    """A shadow-like offset: grows in steps over the first part, then constant (clipped)."""
    grow = np.minimum(np.cumsum(rng.random(n) < 0.1), 25)
    return 3 + grow


@pytest.mark.parametrize("step", [1, 2, 3])
@pytest.mark.parametrize("min_run", [1, 5, 40, 10 ** 6])
def test_pieces_read_the_same_columns_as_fancy_indexing(step, min_run):
    rng = np.random.default_rng(step * 100 + min_run % 97)
    cols = 400
    js = np.arange(0, cols, step)
    x0 = 40
    off1 = _offsets(rng, cols)
    off0 = -(off1 // 2) - 2
    col1 = js + x0 + off1[js]
    col0 = js + x0 + off0[js]
    strip = rng.normal(size=(7, cols + 2 * x0 + 1))
    for c0, c1 in ((col0, col1), (slice(x0, x0 + cols, step), col1), (col0, slice(x0 + 1, x0 + 1 + cols, step))):
        pairs = ColumnPairs(c0, c1, step, min_run=min_run)
        want = strip[:, c1] - strip[:, c0]
        np.testing.assert_array_equal(box(strip, pairs), want)
        covered = np.concatenate([np.arange(p[0].start, p[0].stop) for p in pairs.pieces])
        np.testing.assert_array_equal(covered, np.arange(js.size))  # every anchor once, in order
    for ints in (True, False):
        s = (strip * 1000).astype(np.int32) if ints else strip.astype(np.float32)
        pairs = ColumnPairs(col0, col1, step, min_run=min_run)
        np.testing.assert_array_equal(box(s, pairs), s[:, col1] - s[:, col0])


def test_long_constant_runs_become_slices_and_short_ones_one_gather():
    js = np.arange(1000)
    off = np.minimum(js // 10, 60)  # grows every 10 columns up to column 600, then constant
    pairs = ColumnPairs(slice(5, 1005, 1), js + 5 + off, 1, min_run=256)
    kinds = [(p[0].start, p[0].stop, type(p[2]).__name__) for p in pairs.pieces]
    assert kinds == [(0, 600, "ndarray"), (600, 1000, "slice")]
    assert pairs.gathered == 600
    assert ColumnPairs(slice(5, 1005, 1), js + 5 + off, 1, min_run=10 ** 6).gathered == 1000
    both = ColumnPairs(slice(0, 10, 1), slice(3, 13, 1))
    assert len(both.pieces) == 1 and both.gathered == 0


def test_mismatched_column_counts_are_refused():
    with pytest.raises(ValueError, match="columns"):
        ColumnPairs(np.arange(5), np.arange(6))
    with pytest.raises(ValueError, match="columns"):
        ColumnPairs(slice(0, 5, 1), slice(0, 6, 1))
