"""Mass algebra: the general Dempster rule (reference) against the {T, notT} closed form (SPEC 6, 8)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atr_node.errors import FusionError
from atr_node.fusion.mass import (FRAME_TN, NOT_T, T, accumulate, belief, clamp_mass, closed_form, combine,
                                  combine_all, log_complement, plausibility, simple_support, to_mass)

FT, FN = frozenset({T}), frozenset({NOT_T})


def test_combine_textbook_example():
    # Two sources on {a, b, c}: m1(a) = 0.6, m1(abc) = 0.4; m2(b) = 0.5, m2(bc) = 0.3, m2(abc) = 0.2.
    a, b, c = "a", "b", "c"
    th = frozenset({a, b, c})
    m1 = {frozenset({a}): 0.6, th: 0.4}
    m2 = {frozenset({b}): 0.5, frozenset({b, c}): 0.3, th: 0.2}
    m, k = combine(m1, m2)
    # by hand: conflict = 0.6*0.5 + 0.6*0.3 = 0.48; normaliser 0.52
    assert k == pytest.approx(0.48, abs=1e-15)
    assert m[frozenset({a})] == pytest.approx(0.12 / 0.52, abs=1e-15)
    assert m[frozenset({b})] == pytest.approx(0.20 / 0.52, abs=1e-15)
    assert m[frozenset({b, c})] == pytest.approx(0.12 / 0.52, abs=1e-15)
    assert m[th] == pytest.approx(0.08 / 0.52, abs=1e-15)
    assert belief(m, frozenset({a, b})) == pytest.approx(0.32 / 0.52, abs=1e-15)
    assert plausibility(m, frozenset({c})) == pytest.approx(0.20 / 0.52, abs=1e-15)


def test_two_pieces_closed_form_by_hand():
    # one T piece c = 0.8, one notT piece q = 0.5: a = 0.2, b = 0.5, D = 0.2 + 0.5 - 0.1 = 0.6
    m = closed_form(math.log(0.2), math.log(0.5))
    assert float(m.m_t) == pytest.approx(0.8 * 0.5 / 0.6, rel=1e-14)
    assert float(m.m_n) == pytest.approx(0.5 * 0.2 / 0.6, rel=1e-14)
    assert float(m.m_theta) == pytest.approx(0.1 / 0.6, rel=1e-14)


def reference(cs, qs) -> dict:
    pieces = [simple_support(T, c) for c in cs] + [simple_support(NOT_T, q) for q in qs]
    return combine_all(pieces) if pieces else {FRAME_TN: 1.0}


def test_closed_form_equals_general_rule_on_thousands_of_random_sets():
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(3000):
        nt, nn = rng.integers(0, 6, size=2)
        # mixes of ordinary masses and masses near 0 and 1
        cs = rng.choice([rng.uniform(0, 1), rng.uniform(0, 1e-6), 1 - rng.uniform(0, 1e-6)], size=nt)
        qs = rng.uniform(0, 0.999, size=nn)
        ref = reference(cs.tolist(), qs.tolist())
        la, lb, _ = accumulate(cs, qs, eps=1e-15)
        got = to_mass(closed_form(la, lb))
        for f in (FT, FN, FRAME_TN):
            worst = max(worst, abs(got[f] - ref.get(f, 0.0)))
    assert worst <= 1e-12


def test_closed_form_vectorised_matches_scalar():
    rng = np.random.default_rng(3)
    la = np.log(rng.uniform(1e-3, 1, size=(7, 5)))
    lb = np.log(rng.uniform(1e-3, 1, size=(7, 5)))
    vec = closed_form(la, lb)
    for idx in np.ndindex(la.shape):
        one = closed_form(la[idx], lb[idx])
        assert float(one.m_t) == vec.m_t[idx] and float(one.m_n) == vec.m_n[idx]
    assert np.allclose(vec.m_t + vec.m_n + vec.m_theta, 1.0, atol=1e-15)


unit = st.floats(0.0, 1.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(cs=st.lists(st.floats(0.0, 0.999), max_size=6), qs=st.lists(st.floats(0.0, 0.999), max_size=6),
       seed=st.integers(0, 2**32 - 1))
def test_order_and_grouping_do_not_matter(cs, qs, seed):
    rng = np.random.default_rng(seed)
    pieces = [simple_support(T, c) for c in cs] + [simple_support(NOT_T, q) for q in qs]
    if not pieces:
        return
    ref = combine_all(pieces)
    shuffled = [pieces[i] for i in rng.permutation(len(pieces))]
    cut = int(rng.integers(0, len(pieces) + 1))
    left = combine_all(shuffled[:cut]) if cut else {FRAME_TN: 1.0}
    right = combine_all(shuffled[cut:]) if cut < len(pieces) else {FRAME_TN: 1.0}
    grouped, _ = combine(left, right)
    for f in (FT, FN, FRAME_TN):
        assert grouped.get(f, 0.0) == pytest.approx(ref.get(f, 0.0), abs=1e-12)
    # closed form: accumulators in another order and grouping agree to rounding
    la, lb, _ = accumulate(np.array(cs), np.array(qs), eps=1e-9)
    la2 = sum(log_complement(np.array(cs))[::-1]) if cs else 0.0
    lb2 = sum(log_complement(np.array(qs))[::-1]) if qs else 0.0
    m1, m2 = closed_form(la, lb), closed_form(la2, lb2)
    assert float(m1.m_t) == pytest.approx(float(m2.m_t), abs=1e-12)
    assert float(m1.m_n) == pytest.approx(float(m2.m_n), abs=1e-12)


focal = st.frozensets(st.sampled_from("abc"), min_size=1)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.dictionaries(focal, st.floats(0.01, 1.0), min_size=1, max_size=4),
                          st.booleans()), min_size=2, max_size=4))
def test_general_rule_commutative_and_associative(raw):
    frame = frozenset("abc")
    masses = []
    for d, _ in raw:
        total = sum(d.values())
        m = {k: v / total * 0.9 for k, v in d.items()}
        m[frame] = m.get(frame, 0.0) + 0.1  # keeps every pair combinable
        masses.append(m)
    fwd = combine_all(masses)
    rev = combine_all(masses[::-1])
    for k in set(fwd) | set(rev):
        assert fwd.get(k, 0.0) == pytest.approx(rev.get(k, 0.0), abs=1e-12)
    assert sum(fwd.values()) == pytest.approx(1.0, abs=1e-12)


# ---- SPEC section 8 extremes ----------------------------------------------------------


def test_masses_of_exactly_zero_and_one():
    # zero masses: no evidence at all
    la, lb, n = accumulate([0.0, 0.0], [0.0], eps=1e-9)
    assert (la, lb, n) == (0.0, 0.0, 0)
    m = closed_form(la, lb)
    assert (float(m.m_t), float(m.m_n), float(m.m_theta)) == (0.0, 0.0, 1.0)
    # a mass of 1 is clamped to 1 - eps and counted, and stays finite
    la, lb, n = accumulate([1.0], [], eps=1e-9)
    assert n == 1 and la == pytest.approx(math.log(1e-9), rel=1e-6)
    m = closed_form(la, lb)
    assert float(m.m_t) == pytest.approx(1 - 1e-9, abs=1e-15)


def test_total_conflict_general_rule_raises_and_clamp_avoids_it():
    with pytest.raises(FusionError, match="total conflict"):
        combine({FT: 1.0}, {FN: 1.0})
    la, lb, n = accumulate([1.0], [1.0], eps=1e-9)
    assert n == 2
    m = closed_form(la, lb)
    # with both clamped to 1 - eps: m(T) = m(notT) by symmetry, finite and summing to 1
    assert float(m.m_t) == pytest.approx(float(m.m_n), rel=1e-12)
    assert float(m.m_t + m.m_n + m.m_theta) == pytest.approx(1.0, abs=1e-15)
    ref = combine_all([simple_support(T, 1 - 1e-9), simple_support(NOT_T, 1 - 1e-9)])
    assert float(m.m_t) == pytest.approx(ref[FT], abs=1e-12)


def test_clamp_rejects_bad_masses():
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(FusionError, match="outside"):
            clamp_mass(np.array([0.5, bad]), 1e-9)
    c = clamp_mass(np.array([0.2, 1.0, 1 - 1e-12]), 1e-9)
    assert c.n_clamped == 2 and c.mass.max() == 1 - 1e-9


def test_hundred_thousand_pieces_on_one_cell():
    rng = np.random.default_rng(11)
    cs = rng.uniform(0.0, 0.3, size=50_000)
    qs = rng.uniform(0.0, 0.3, size=50_000)
    la, lb, _ = accumulate(cs, qs, eps=1e-9)
    m = closed_form(la, lb)
    assert np.isfinite([m.m_t, m.m_n, m.m_theta]).all()
    # reference: the general rule applied piece by piece (1e5 combinations, float64)
    acc = {FRAME_TN: 1.0}
    order = rng.permutation(100_000)
    for k in order:
        piece = simple_support(T, cs[k]) if k < 50_000 else simple_support(NOT_T, qs[k - 50_000])
        acc, _ = combine(acc, piece)
    assert float(m.m_t) == pytest.approx(acc.get(FT, 0.0), abs=1e-9)
    assert float(m.m_n) == pytest.approx(acc.get(FN, 0.0), abs=1e-9)
    # many tiny pieces: the log domain keeps digits that a product of (1 - c) would lose
    la = float(np.sum(log_complement(np.full(100_000, 1e-17))))
    assert la == pytest.approx(-1e-12, rel=1e-9)
    assert float(closed_form(la, 0.0).m_t) == pytest.approx(1e-12, rel=1e-9)


def test_accumulators_of_minus_infinity():
    inf = -np.inf
    m = closed_form(np.array([inf, inf, 0.0, inf, -5.0]), np.array([0.0, -3.0, inf, inf, inf]))
    assert m.m_t.tolist()[:3] == [1.0, 1.0, 0.0]
    assert m.m_n.tolist()[:3] == [0.0, 0.0, 1.0]
    assert m.m_theta.tolist()[:3] == [0.0, 0.0, 0.0]
    # both infinite: total conflict, flagged, finite answer
    assert m.conflict.tolist() == [False, False, False, True, False]
    assert (m.m_t[3], m.m_n[3], m.m_theta[3]) == (0.5, 0.5, 0.0)
    assert (m.m_t[4], m.m_n[4]) == (0.0, 1.0)
    assert np.isfinite(m.m_t).all() and np.isfinite(m.m_n).all()


def test_masses_within_1e15_of_zero_and_one():
    m = closed_form(log_complement(1e-16), 0.0)
    assert float(m.m_t) == pytest.approx(1e-16, rel=1e-12)
    m = closed_form(log_complement(1 - 1e-15), log_complement(0.5))
    ref = combine_all([simple_support(T, 1 - 1e-15), simple_support(NOT_T, 0.5)])
    assert float(m.m_t) == pytest.approx(ref[FT], abs=1e-12)
    assert float(m.m_theta) == pytest.approx(ref[FRAME_TN], rel=1e-3)


def test_bad_accumulators_rejected():
    with pytest.raises(FusionError):
        closed_form(0.1, 0.0)
    with pytest.raises(FusionError):
        closed_form(np.nan, 0.0)
