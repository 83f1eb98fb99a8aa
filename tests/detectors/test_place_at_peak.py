"""``place_at_peak`` (``detectors.relocate``): a detection moved to the reference map's first
maximum over its template window, checked against a direct loop, and the cases where it stays."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from atr_node.detectors import Detection, place_at_peak

ROW0, LENGTH, ECHO = -3, 7, 4


def det(row: int, col: int, **kw) -> Detection:
    return Detection("lac", row, col, 2.5, 10.0 + 0.1 * col, 0.4, 0.6, 9, **kw)


def place(found, ref, shadow):
    return place_at_peak(found, ref, row0=ROW0, length_px=LENGTH, echo_px=ECHO, shadow_px=shadow,
                         range0_m=10.0, dr_m=0.1)


def direct(x: Detection, ref: np.ndarray, shadow: np.ndarray) -> tuple[int, int]:
    best, at = -math.inf, (x.row, x.col)
    for r in range(x.row + ROW0, x.row + ROW0 + LENGTH):
        for c in range(x.col - ECHO, x.col + int(shadow[x.col])):
            if 0 <= r < ref.shape[0] and 0 <= c < ref.shape[1] and math.isfinite(ref[r, c]) and ref[r, c] > best:
                best, at = float(ref[r, c]), (r, c)
    return at if best > 0 else (x.row, x.col)


def test_random_maps_agree_with_a_direct_loop():
    rng = np.random.default_rng(5)
    for _ in range(40):
        rows, cols = rng.integers(8, 40), rng.integers(10, 60)
        ref = rng.normal(0.0, 1.0, (rows, cols)).round(1)  # rounded: ties occur
        ref[rng.random((rows, cols)) < 0.2] = np.nan
        shadow = rng.integers(1, 9, cols)
        found = [det(int(rng.integers(0, rows)), int(rng.integers(0, cols))) for _ in range(6)]
        got = place(found, ref, shadow)
        assert len(got) == len(found)
        for x, y in zip(found, got):
            assert (y.row, y.col) == direct(x, ref, shadow)
            assert y.range_m == pytest.approx(10.0 + 0.1 * y.col, abs=1e-12)
            assert dataclasses.replace(y, row=x.row, col=x.col, range_m=x.range_m) == x


def test_stays_without_a_positive_peak_and_keeps_an_objects_centre():
    shadow = np.full(30, 5)
    ref = np.full((20, 30), -1.0)
    x = det(10, 15)
    assert place([x], ref, shadow) == [x]  # no echo brighter than its shadow
    ref[:] = np.nan
    assert place([x], ref, shadow) == [x]  # nothing scored in the window
    ref = np.zeros((20, 30))
    ref[2, 2] = 9.0
    wreck = det(3, 3, length_m=12.0, width_m=3.0, axis_deg=0.0)
    assert place([wreck], ref, shadow) == [wreck]
    assert place([], ref, shadow) == []


def test_window_clipped_at_the_map_edge_and_first_of_equal_maxima():
    shadow = np.full(12, 3)
    ref = np.zeros((6, 12))
    ref[0, 0] = ref[0, 1] = ref[1, 0] = 4.0  # equal maxima: the first in row-major order
    got = place([det(1, 2)], ref, shadow)[0]  # window rows [-2, 5), columns [-2, 5): clipped
    assert (got.row, got.col) == (0, 0)
    ref[5, 11] = 7.0  # outside that window: not reached
    assert place([det(1, 2)], ref, shadow)[0].col == 0
