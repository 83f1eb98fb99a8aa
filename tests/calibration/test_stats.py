"""Statistics of SPEC section 5 against direct float64 references, published values and the
SPEC section 8 extremes (empty and single-sample histograms and range bins)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import isotonic_regression

from atr_node.calibration.stats import (confidence_curve, dobeck_threshold, isotonic_increasing, pd_at,
                                        pd_curve, range_edges, smoothed_proportion, survival, survival_counts,
                                        wilson_interval)


# -- survival functions ----------------------------------------------------------------------

def test_survival_counts_match_a_direct_count(rng):
    x = rng.normal(size=500)
    x[::17] = np.nan
    at = np.concatenate([rng.normal(size=50), x[:20]])  # includes exact sample values (ties)
    ref = np.array([sum(1 for v in x if np.isfinite(v) and v >= a) for a in at if np.isfinite(a)])
    got = survival_counts(x, at[np.isfinite(at)])
    np.testing.assert_array_equal(got, ref)


def test_smoothing_never_reaches_0_or_1_and_empty_is_one_half():
    k = np.array([0, 0, 5, 10, 0, 1])
    n = np.array([0, 10, 10, 10, 1, 1])
    j = smoothed_proportion(k, n, smoothing="jeffreys")
    lap = smoothed_proportion(k, n, smoothing="laplace")
    np.testing.assert_allclose(j, (k + 0.5) / (n + 1.0), rtol=0, atol=1e-15)
    np.testing.assert_allclose(lap, (k + 1.0) / (n + 2.0), rtol=0, atol=1e-15)
    assert np.all((j > 0) & (j < 1)) and np.all((lap > 0) & (lap < 1))
    assert j[0] == 0.5 and lap[0] == 0.5


def test_survival_of_empty_and_single_sample():
    assert survival([], [0.0, 1.0]).tolist() == [0.5, 0.5]
    assert survival([np.nan], [0.0]).tolist() == [0.5]
    # one sample at 1: P(X >= 0) = (1 + 1/2) / 2, P(X >= 2) = (0 + 1/2) / 2
    np.testing.assert_allclose(survival([1.0], [0.0, 1.0, 2.0]), [0.75, 0.75, 0.25])
    np.testing.assert_allclose(survival([1.0], [0.0, 2.0], smoothing=None), [1.0, 0.0])


# -- Wilson interval -------------------------------------------------------------------------

@pytest.mark.parametrize("k, n, low, high", [
    # Newcombe, Stat. Med. 17 (1998) 857-872, table I, method 3 (Wilson score, no correction)
    (81, 263, 0.2553, 0.3662),
    (15, 148, 0.0624, 0.1605),
    (0, 20, 0.0, 0.1611),
    (1, 29, 0.0061, 0.1718),
])
def test_wilson_matches_published_values(k, n, low, high):
    lo, hi = wilson_interval(k, n)
    assert lo == pytest.approx(low, abs=5e-5) and hi == pytest.approx(high, abs=5e-5)


def test_wilson_edge_cases():
    lo, hi = wilson_interval(np.array([0, 0, 1, 1]), np.array([0, 1, 1, 2]))
    assert lo[0] == 0.0 and hi[0] == 1.0  # empty: know nothing
    assert lo[1] == 0.0 and 0 < hi[1] < 1
    assert 0 < lo[2] < 1 and hi[2] == pytest.approx(1.0)
    assert np.all(lo <= hi)
    # all successes: the upper bound is exactly 1 (closed form), so Pd = 1 lies inside
    lo, hi = wilson_interval(np.array([7, 150, 0]), np.array([7, 150, 150]))
    assert hi[0] == 1.0 and hi[1] == 1.0 and lo[2] == 0.0


# -- isotonic fit ----------------------------------------------------------------------------

def test_isotonic_exact_small_case():
    np.testing.assert_allclose(isotonic_increasing([1.0, 3.0, 2.0, 4.0]), [1.0, 2.5, 2.5, 4.0])
    np.testing.assert_allclose(isotonic_increasing([3.0, 1.0], [1.0, 3.0]), [1.5, 1.5])
    assert isotonic_increasing([]).size == 0
    assert isotonic_increasing([0.3]).tolist() == [0.3]


def test_isotonic_matches_scipy_reference(rng):
    y = np.cumsum(rng.normal(size=300)) * 0.1 + rng.normal(size=300)
    w = rng.uniform(0.5, 3.0, size=300)
    ref = isotonic_regression(y, weights=w, increasing=True).x
    np.testing.assert_allclose(isotonic_increasing(y, w), ref, rtol=0, atol=1e-12)


# -- confidence (eq. 6) ----------------------------------------------------------------------

def _direct_confidence(x_t, x_n, tau, gamma, prior, a=0.5):
    """The definition of stats.confidence_curve, written out with Python loops."""
    t = [v for v in x_t if np.isfinite(v)]
    n = [v for v in x_n if np.isfinite(v)]
    st_ = (sum(v > tau for v in t) + a) / (len(t) + 2 * a)
    sn_ = (sum(v > tau for v in n) + a) / (len(n) + 2 * a)
    pi = st_ * prior / (st_ * prior + sn_ * (1 - prior))  # eq. 6 at tau
    ta = [v for v in t if v > tau]
    na = [v for v in n if v > tau]
    out = []
    for g in gamma:
        s1 = (sum(v >= g for v in ta) + a) / (len(ta) + 2 * a)
        s0 = (sum(v >= g for v in na) + a) / (len(na) + 2 * a)
        out.append(pi * s1 / (pi * s1 + (1 - pi) * s0))
    return pi, np.array(out)


def test_confidence_matches_its_definition_and_starts_near_equation_6(rng):
    x_t = rng.normal(3.0, 1.0, size=400)
    x_n = rng.normal(0.0, 1.0, size=4000)
    for tau in (0.5, 1.5, 2.5):
        c = confidence_curve(x_t, x_n, tau, prior_target=0.1, n_points=12)
        pi, ref = _direct_confidence(x_t, x_n, tau, c.gamma, 0.1)
        assert c.gamma[0] == tau
        np.testing.assert_allclose(c.raw, ref, rtol=1e-12)
        # the table is the raw ratio, or its isotonic fit where the ratio dips (sparse tail)
        if c.isotonic_adjusted:
            assert np.any(np.diff(c.raw) < 0)
            assert c.max_adjustment == pytest.approx(np.max(np.abs(c.confidence - c.raw)))
        else:
            np.testing.assert_array_equal(c.confidence, c.raw)
        # at the threshold: eq. 6, up to the smoothing of the conditional survival functions
        assert c.confidence[0] == pytest.approx(pi, rel=0.01)


def test_confidence_converges_to_posterior_given_gamma_exceeded(rng):
    # Many samples: c(g; tau) -> P(T | Gamma >= g) = S_T(g) P / (S_T(g) P + S_N(g) (1-P)), closed form
    # for two normal laws.
    from scipy.stats import norm

    x_t = rng.normal(2.0, 1.0, size=200_000)
    x_n = rng.normal(0.0, 1.0, size=200_000)
    c = confidence_curve(x_t, x_n, 1.0, prior_target=0.1, gamma_max=3.0, n_points=9)
    s_t, s_n = norm.sf(c.gamma, 2.0), norm.sf(c.gamma, 0.0)
    ref = s_t * 0.1 / (s_t * 0.1 + s_n * 0.9)
    np.testing.assert_allclose(c.confidence, ref, atol=0.01)


def test_confidence_isotonic_where_the_ratio_dips():
    # Non-targets cluster at high gamma: the raw ratio falls there and must be flattened.
    x_t = np.concatenate([np.full(50, 2.0), np.full(50, 6.0)])
    x_n = np.concatenate([np.full(50, 1.5), np.full(40, 4.0), np.full(5, 5.0)])
    c = confidence_curve(x_t, x_n, 1.0, prior_target=0.1, n_points=50)
    assert c.isotonic_adjusted and c.max_adjustment > 0
    assert np.all(np.diff(c.confidence) >= 0)
    assert np.all((c.confidence > 0) & (c.confidence < 1))


@pytest.mark.parametrize("x_t, x_n", [
    ([], []), ([np.nan], [np.nan]), ([2.0], []), ([], [2.0]), ([2.0], [2.0]), ([0.5], [0.1]),
])
def test_confidence_defined_for_empty_and_single_samples(x_t, x_n):
    c = confidence_curve(np.array(x_t), np.array(x_n), 1.0, prior_target=0.1, n_points=5)
    assert c.gamma.size >= 5 and c.gamma[0] == 1.0 and np.all(np.diff(c.gamma) > 0)
    assert np.all(np.isfinite(c.confidence))
    assert np.all((c.confidence > 0) & (c.confidence < 1))
    assert np.all(np.diff(c.confidence) >= 0)
    if not x_t and not x_n:
        np.testing.assert_allclose(c.confidence, 0.1)  # no data: the prior


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-10, 10), max_size=30), st.lists(st.floats(-10, 10), max_size=30),
       st.floats(-5, 5), st.floats(0.01, 0.99), st.sampled_from(["jeffreys", "laplace"]))
def test_confidence_property_in_open_unit_interval_and_monotone(x_t, x_n, tau, prior, smoothing):
    c = confidence_curve(np.array(x_t), np.array(x_n), tau, prior_target=prior, n_points=16, smoothing=smoothing)
    assert np.all((c.confidence > 0) & (c.confidence < 1))
    assert np.all(np.diff(c.confidence) >= 0)


# -- P(y) ------------------------------------------------------------------------------------

def test_pd_curve_counts_match_a_direct_loop(rng):
    r = rng.uniform(12.0, 97.0, size=700)
    x = rng.normal(1.0, 1.0, size=700)
    x[::50] = np.nan  # not covered: not counted
    tau = 0.7
    y = pd_curve(r, x, tau, bin_m=10.0)
    assert y.edges_m[0] == 10.0 and y.edges_m[-1] == 100.0
    for b in range(y.edges_m.size - 1):
        sel = [i for i in range(r.size) if y.edges_m[b] <= r[i] < y.edges_m[b + 1] and np.isfinite(x[i])]
        k = sum(x[i] > tau for i in sel)
        assert y.injected[b] == len(sel) and y.detected[b] == k
        assert y.pd[b] == pytest.approx((k + 0.5) / (len(sel) + 1.0))
        lo, hi = wilson_interval(k, len(sel))
        assert y.low[b] == pytest.approx(lo) and y.high[b] == pytest.approx(hi)


def test_pd_empty_and_single_sample_bins():
    edges = np.array([0.0, 10.0, 20.0, 30.0])
    y = pd_curve([5.0], [3.0], 1.0, edges_m=edges)
    assert y.injected.tolist() == [1, 0, 0] and y.detected.tolist() == [1, 0, 0]
    assert y.pd[0] == pytest.approx(0.75) and y.pd[1] == 0.0 and y.pd[2] == 0.0
    assert y.low[1] == 0.0 and y.high[1] == 1.0
    empty = pd_curve([], [], 1.0, bin_m=10.0)
    assert empty.injected.sum() == 0 and np.all(empty.pd == 0.0)


def test_pd_is_zero_outside_the_calibrated_span():
    y = pd_curve(np.linspace(20, 59.5, 100), np.ones(100), 0.5, bin_m=10.0)
    assert y.edges_m[0] == 20.0 and y.edges_m[-1] == 60.0
    r = np.array([-5.0, 0.0, 19.99, 20.0, 25.0, 40.0, 59.0, 60.0, 60.01, 200.0, np.nan])
    p = pd_at(y.edges_m, y.pd, r)
    assert p[0] == p[1] == p[2] == 0.0 and p[-1] == 0.0 and p[-2] == 0.0 and p[-3] == 0.0
    assert np.all(p[3:8] > 0.9)


def test_range_edges_cover_all_ranges():
    e = range_edges(np.array([3.2, 47.0, 50.0]), 5.0)
    assert e[0] == 0.0 and e[-1] == 55.0 and np.allclose(np.diff(e), 5.0)


# -- Dobeck thresholds -----------------------------------------------------------------------

def _brute_dobeck(x, pd_target):
    x = np.sort(x[np.isfinite(x)])
    cands = np.concatenate([[np.nextafter(x[0], -np.inf)], x])
    ok = [t for t in cands if np.mean(x > t) >= pd_target]
    return max(ok)


@pytest.mark.parametrize("n", [1, 2, 19, 20, 21, 100, 2000])
def test_dobeck_is_the_largest_threshold_at_the_pd_target(rng, n):
    x = np.round(rng.normal(size=n), 1)  # ties on purpose
    tau = dobeck_threshold(x, 0.95, default=9.0)
    assert tau == _brute_dobeck(x, 0.95)
    assert np.mean(x > tau) >= 0.95
    # any larger response value fails the target
    above = np.unique(x[x > tau])
    if above.size:
        assert np.mean(x > above[0]) < 0.95


def test_dobeck_edge_cases():
    assert dobeck_threshold(np.array([]), 0.95, default=1.25) == 1.25
    assert dobeck_threshold(np.array([np.nan, np.nan]), 0.95, default=1.25) == 1.25
    tau = dobeck_threshold(np.full(50, 2.0), 0.95, default=0.0)
    assert tau < 2.0 and np.all(np.full(50, 2.0) > tau)
