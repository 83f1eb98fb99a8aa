"""The injected calibration population (issue 17 item 5): draws, reflectivity, burial, tilt."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from atr_node.config import PopulationSettings, SimulationSettings, load_settings
from atr_node.errors import ConfigError, GeometryError
from atr_node.simulation.inject import Placement, draw_placement, inject_targets
from atr_node.simulation.meshes import box, builtin_mesh

H, DR, DX = 14.0, 0.1, 0.1
SPANS = dict(row_span=(50.0, 950.0), range_span_m=(10.0, 60.0))


def draws(pop, seed, n=2000):
    rng = np.random.default_rng(seed)
    return [draw_placement(rng, population=pop, **SPANS) for _ in range(n)]


def test_varied_draws_lie_within_their_ranges_and_cover_them():
    pop = PopulationSettings(mode="varied")
    ps = draws(pop, 1)
    varied = [p for p in ps if not p.nominal]
    nominal = [p for p in ps if p.nominal]
    # share of nominal targets: binomial(2000, p), sigma <= 0.0112, so 0.05 is > 4 sigma
    assert abs(len(nominal) / len(ps) - pop.nominal_fraction) < 0.05
    for p in nominal:
        assert (p.scale, p.roll_deg, p.pitch_deg, p.burial_m, p.reflectivity_db) == ((1.0, 1.0, 1.0), 0, 0, 0, 0)
    lo_xy = pop.size_scale[0] * pop.axis_scale[0]
    hi_xy = pop.size_scale[1] * pop.axis_scale[1]
    lo_z, hi_z = pop.size_scale[0] * pop.height_scale[0], pop.size_scale[1] * pop.height_scale[1]
    refl = np.array([p.reflectivity_db for p in varied])
    tilt = np.array([[p.roll_deg, p.pitch_deg] for p in varied])
    for p in varied:
        sx, sy, sz = p.scale
        assert lo_xy <= sx <= hi_xy and lo_xy <= sy <= hi_xy and lo_z <= sz <= hi_z
        # the size factor is shared: each axis ratio stays within the per-axis factors' ratios
        assert pop.axis_scale[0] / pop.axis_scale[1] - 1e-12 <= sx / sy <= pop.axis_scale[1] / pop.axis_scale[0] + 1e-12
        assert pop.axis_scale[0] / pop.height_scale[1] - 1e-12 <= sx / sz <= pop.axis_scale[1] / pop.height_scale[0] + 1e-12
        m = builtin_mesh(p.shape).scaled(*p.scale).tilted(roll_deg=p.roll_deg, pitch_deg=p.pitch_deg)
        frac = p.burial_m / m.height_m
        assert pop.burial_fraction[0] - 1e-12 <= frac <= pop.burial_fraction[1] + 1e-12
        assert 50.0 <= p.row <= 950.0 and 10.0 <= p.range_m <= 60.0 and 0.0 <= p.heading_deg < 360.0
        assert p.shape in pop.shapes
    assert refl.min() >= -10.0 and refl.max() <= 10.0 and refl.min() < -9.5 and refl.max() > 9.5
    assert np.abs(tilt).max() <= 20.0 and np.abs(tilt).max() > 19.5
    assert {p.shape for p in varied} == set(pop.shapes)


def test_draws_are_reproducible_by_seed_and_fixed_mode_keeps_the_old_draws():
    pop = PopulationSettings(mode="varied")
    assert draws(pop, 7, 300) == draws(pop, 7, 300)
    assert draws(pop, 7, 300) != draws(pop, 8, 300)
    # "fixed" (and no population at all) draws exactly what the injector drew before issue 17
    rng = np.random.default_rng(3)
    old = [Placement(shape=str(rng.choice(("cylinder", "cone", "wedge", "sphere"))), row=float(rng.uniform(50.0, 950.0)),
                     range_m=float(rng.uniform(10.0, 60.0)), heading_deg=float(rng.uniform(0.0, 360.0)))
           for _ in range(50)]
    assert draws(PopulationSettings(mode="fixed"), 3, 50) == old
    assert draws(None, 3, 50) == old
    # narrow ranges pin every trait
    pin = PopulationSettings(mode="varied", size_scale=(1.2, 1.2), axis_scale=(1.0, 1.0), height_scale=(0.5, 0.5), tilt_deg=0.0,
                             burial_fraction=(0.25, 0.25), reflectivity_db=(-3.0, -3.0), nominal_fraction=0.0)
    for p in draws(pin, 2, 20):
        assert p.scale == pytest.approx((1.2, 1.2, 0.6)) and p.reflectivity_db == -3.0 and not p.nominal
        assert p.burial_m == pytest.approx(0.25 * builtin_mesh(p.shape).height_m * 0.6)


def test_injection_with_a_population_is_reproducible_and_records_the_traits():
    host = np.random.default_rng(0).exponential(1.0, (1200, 600)).astype(np.float32)
    kw = dict(range0_m=5.0, dr_m=DR, dx_m=DX, altitude_m=H, n_targets=10, population=PopulationSettings(mode="varied"))
    a = inject_targets(host, rng=np.random.default_rng(5), **kw)
    b = inject_targets(host, rng=np.random.default_rng(5), **kw)
    assert a[1] == b[1] and np.array_equal(a[0], b[0]) and len(a[1]) >= 6
    assert any(not t.nominal for t in a[1])
    for t in a[1]:
        assert -10.0 <= t.reflectivity_db <= 10.0 and 0.0 < t.height_m < 3.0


@pytest.mark.parametrize("x_db", [6.0, -7.0, 10.0])
def test_reflectivity_scales_the_rendered_echo_by_its_power_ratio(x_db):
    """+X dB multiplies the echo intensity by 10^(X/10): with the same speckle draws, the
    rendered image minus the echo-free render (-300 dB) scales by exactly that ratio."""
    host = np.random.default_rng(1).exponential(1.0, (300, 500)).astype(np.float32)

    def render(db):
        pl = [Placement("cylinder", row=150.0, range_m=30.0, heading_deg=10.0, reflectivity_db=db)]
        out, tg = inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, placements=pl,
                                 rng=np.random.default_rng(9))
        return out.astype(np.float64), tg[0]

    base, _ = render(-300.0)
    ref, t0 = render(0.0)
    out, tx = render(x_db)
    e0, ex = ref - base, out - base
    lit = e0 > 1e-3 * e0.max()
    assert lit.sum() > 20
    np.testing.assert_allclose(ex[lit] / e0[lit], 10.0 ** (x_db / 10.0), rtol=1e-4)
    assert not np.any(ex[~lit] > 1e-3 * ex.max())  # nothing else changed
    assert tx.reflectivity_db == x_db and tx.rho_echo == t0.rho_echo  # the model's ratio, before the gain


def test_a_buried_target_shows_its_visible_height():
    """A box of height 1 m buried by 40 % casts the shadow of a 0.6 m box: h r / (H - h)
    (SPEC section 4) with h the visible height, counted on the rendered pixels."""
    host = np.ones((200, 700), dtype=np.float32)
    sim = SimulationSettings(multipath_db=40.0)  # shadows far below the 0.5 cut
    r, width = 30.0, 1.0
    lengths = {}
    for frac in (0.0, 0.4):
        pop = PopulationSettings(mode="varied", shapes=("box",), size_scale=(1.0, 1.0), axis_scale=(1.0, 1.0),
                                 height_scale=(2.0, 2.0), tilt_deg=0.0, burial_fraction=(frac, frac),
                                 reflectivity_db=(0.0, 0.0), nominal_fraction=0.0)
        p = draw_placement(np.random.default_rng(0), population=pop, row_span=(100.0, 100.0), range_span_m=(r, r))
        p = dataclasses.replace(p, heading_deg=0.0)
        out, tg = inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, placements=[p],
                                 rng=np.random.default_rng(1), simulation=sim)
        h_visible = 1.0 * (1.0 - frac)
        assert tg[0].height_m == pytest.approx(h_visible)
        assert p.burial_m == pytest.approx(frac * 1.0)
        far = r + width / 2
        cols = np.arange(host.shape[1]) * DR
        lengths[frac] = float((out[100, cols > far] < 0.5).sum() * DR)
        assert lengths[frac] == pytest.approx(h_visible * far / (H - h_visible), abs=2 * DR)
    assert lengths[0.4] < lengths[0.0] - 0.5


def test_tilt_rests_the_mesh_on_the_seabed_exact_box():
    b = box(2.0, 1.0, 0.5)
    t = b.tilted(pitch_deg=30.0)
    lo, hi = t.bounds_m
    # a 2 m x 0.5 m side rotated by 30 deg: height 2 sin 30 + 0.5 cos 30
    assert hi[2] == pytest.approx(2.0 * 0.5 + 0.5 * math.cos(math.radians(30.0)), abs=1e-12)
    assert lo[2] == pytest.approx(0.0, abs=1e-12)
    assert lo[0] + hi[0] == pytest.approx(0.0, abs=1e-12) and lo[1] + hi[1] == pytest.approx(0.0, abs=1e-12)
    rolled = b.tilted(roll_deg=90.0)
    assert rolled.height_m == pytest.approx(1.0, abs=1e-12)  # lies on its side: the width is the height
    s = b.scaled(1.5, 2.0, 0.5)
    assert np.allclose(s.bounds_m[1] - s.bounds_m[0], [3.0, 2.0, 0.25])
    with pytest.raises(GeometryError):
        b.scaled(0.0, 1.0, 1.0)


def test_population_settings_are_validated(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("[calibration.population]\nreflectivity_db = [10.0, -10.0]\n")
    with pytest.raises(ConfigError, match="calibration.population.reflectivity_db"):
        load_settings(p)
    p.write_text("[calibration.population]\nshapes = [\"torpedo\"]\n")
    with pytest.raises(ConfigError, match="calibration.population.shapes"):
        load_settings(p)
    p.write_text("[calibration.population]\nmode = \"fixed\"\ntilt_deg = 5\n")
    s = load_settings(p)
    assert s.calibration.population.mode == "fixed" and s.calibration.population.tilt_deg == 5.0
