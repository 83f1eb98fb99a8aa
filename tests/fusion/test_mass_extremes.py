"""Dempster-Shafer at very large accumulators (issue 21 item 8, SPEC 6 and 8).

The closed form is checked against an independent evaluation of ``u b / (a + u b)`` in
arbitrary precision (``decimal``, whose exponent range holds ``exp(-1e17)``), against the
limits the closed form must reach when ``exp(L)`` is far below float64, and against the
general-frame rule (:func:`combine_all`) on chains of 10^4 near-certain pieces in any order.
"""

from __future__ import annotations

import decimal
import math
import random

import numpy as np
import pytest

from atr_node.fusion.mass import FRAME_TN, NOT_T, T, accumulate, closed_form, combine_all, simple_support

FT, FN = frozenset({T}), frozenset({NOT_T})


def _exact(la: float, lb: float) -> tuple[float, float, float]:
    """(m(T), m(notT), m(Theta)) from the textbook closed form in 60-digit decimal arithmetic."""
    ctx = decimal.Context(prec=60, Emin=-999999999999999999, Emax=999999999999999999)
    a = ctx.exp(decimal.Decimal(la))
    b = ctx.exp(decimal.Decimal(lb))
    u, w = ctx.subtract(1, a), ctx.subtract(1, b)
    d = ctx.add(a, ctx.multiply(u, b))
    return (float(ctx.divide(ctx.multiply(u, b), d)), float(ctx.divide(ctx.multiply(w, a), d)),
            float(ctx.divide(ctx.multiply(a, b), d)))


@pytest.mark.parametrize("mag", [1e3, 2.07e7, 1e12, 1e15, 1e16, 1e17])
@pytest.mark.parametrize("offset", [0.0, 1.0, -2.5, 30.0])
def test_closed_form_against_arbitrary_precision(mag, offset):
    # L_N = L_T + offset: the masses depend on the difference (b / a = e^offset), which the
    # old evaluation lost in log D once |L| reached 1e15-1e16 (m(T) = m(notT) = 1 at 1e16)
    la, lb = -mag, -mag + offset
    ref = _exact(la, lb)
    m = closed_form(la, lb)
    got = (float(m.m_t), float(m.m_n), float(m.m_theta))
    for g, r in zip(got, ref):
        assert g == pytest.approx(r, rel=1e-12, abs=1e-300)
    assert sum(got) == pytest.approx(1.0, abs=2e-16)
    assert float(m.bel) <= float(m.pl)


@pytest.mark.parametrize("big", [1e16, 1e100, 1e300, 1.7e308])
def test_closed_form_limits_far_below_float64(big):
    # a = b = exp(-big): equal evidence both ways, m = (1/2, 1/2, 0)
    m = closed_form(-big, -big)
    assert (float(m.m_t), float(m.m_n), float(m.m_theta)) == (0.5, 0.5, 0.0)
    # L_N = 2 L_T (or the other way round): b / a = exp(-big) -> 0, so m(notT) -> 1
    m = closed_form(-big / 2, -big)
    assert (float(m.m_t), float(m.m_n), float(m.m_theta)) == (0.0, 1.0, 0.0)
    m = closed_form(-big, -big / 2)
    assert (float(m.m_t), float(m.m_n), float(m.m_theta)) == (1.0, 0.0, 0.0)
    # one side certain (-inf), the other finite however large
    m = closed_form(-np.inf, -big)
    assert (float(m.m_t), float(m.m_n), float(m.m_theta)) == (1.0, 0.0, 0.0)
    m = closed_form(-big, -np.inf)
    assert (float(m.m_t), float(m.m_n), float(m.m_theta)) == (0.0, 1.0, 0.0)
    assert not m.conflict


def test_million_maximal_pieces_each_way_sum_to_one():
    # 10^6 + 10^6 pieces clamped to 1 - 1e-9 (the grid's largest): before, the masses summed
    # to 1 + 1.8e-9
    la, lb, n = accumulate(np.ones(1_000_000), np.ones(1_000_000), eps=1e-9)
    assert n == 2_000_000
    m = closed_form(la, lb)
    assert float(m.m_t + m.m_n + m.m_theta) == pytest.approx(1.0, abs=2e-16)
    assert float(m.m_t) == float(m.m_n) == pytest.approx(0.5, abs=1e-15)
    # vectorised over many such cells, one piece more on T each time: e^{|log 1e-9|} more T
    la = la + np.arange(4) * math.log(1e-9)
    m = closed_form(la, np.full(4, lb))
    ref = [_exact(float(x), lb) for x in la]
    for k in range(4):
        assert float(m.m_t[k]) == pytest.approx(ref[k][0], rel=1e-9, abs=1e-300)
        assert float(m.m_n[k]) == pytest.approx(ref[k][1], rel=1e-9, abs=1e-300)
    assert np.all(m.m_t <= 1.0 - m.m_n)


def test_hundred_thousand_pieces_near_one():
    c = 1.0 - 1e-12
    lt, ln, _ = accumulate(np.full(100_000, c), np.full(100_000, c), eps=1e-15)
    m = closed_form(lt, ln)
    assert (float(m.m_t), float(m.m_n), float(m.m_theta)) == (0.5, 0.5, 0.0)
    # one T piece more: T wins by 1 - c on notT's side, b / a = 1 / (1 - c)... m(notT) ~ 1e-12
    lt1, _, _ = accumulate(np.full(100_001, c), [], eps=1e-15)
    m = closed_form(lt1, ln)
    assert float(m.m_n) == pytest.approx(1e-12, rel=1e-3)
    assert float(m.m_t) == pytest.approx(1.0 - 1e-12, abs=1e-15)


def _pieces(n_t: int, n_n: int, c: float) -> list[dict]:
    return [simple_support(T, c) for _ in range(n_t)] + [simple_support(NOT_T, c) for _ in range(n_n)]


@pytest.mark.parametrize("n_t,n_n", [(10_000, 10_000), (10_000, 9_999), (30, 29)])
def test_general_rule_is_order_free_at_near_total_conflict(n_t, n_n):
    # before: T pieces first gave (1, 0), notT first (0, 1), alternating (1/2, 1/2): m(Theta)
    # underflowed to 0 and the rest of the chain saw a categorical mass
    c = 1.0 - 1e-12
    pieces = _pieces(n_t, n_n, c)
    rng = random.Random(5)
    shuffled = pieces[:]
    rng.shuffle(shuffled)
    alternating = [p for pair in zip(pieces[:n_t], pieces[n_t:]) for p in pair] + pieces[n_n:n_t]
    orders = {"T first": pieces, "notT first": pieces[n_t:] + pieces[:n_t], "shuffled": shuffled,
              "alternating": alternating}
    lt, ln, _ = accumulate(np.full(n_t, c), np.full(n_n, c), eps=1e-15)
    cf = closed_form(lt, ln)
    for name, seq in orders.items():
        m = combine_all(seq)
        assert m.get(FT, 0.0) == pytest.approx(float(cf.m_t), abs=1e-9), name
        assert m.get(FN, 0.0) == pytest.approx(float(cf.m_n), abs=1e-9), name
        assert m.get(FRAME_TN, 0.0) == pytest.approx(float(cf.m_theta), abs=1e-12), name
        assert sum(m.values()) == pytest.approx(1.0, abs=1e-12), name


def test_general_rule_still_refuses_exact_total_conflict():
    from atr_node.errors import FusionError
    with pytest.raises(FusionError, match="total conflict"):
        combine_all([{FT: 1.0}, {FN: 1.0}])
