"""Target injection: contrast against the sonar model, truth, footprints, NaN, SAS beam."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.config import SensorSettings, SimulationSettings, TemplateSettings
from atr_node.errors import GeometryError
from atr_node.simulation.inject import Placement, inject_targets
from atr_node.simulation.meshes import box, builtin_mesh, place
from atr_node.simulation.performance import SonarModel
from atr_node.simulation.raytrace import trace
from atr_node.simulation.seabed import seabed_pixels
from atr_node.simulation.signature import along_track_kernel, background_curve, blur_along_track

H, DR, DX = 14.0, 0.1, 0.1


def host_tile(rng, rows=600, cols=1000, k_order=50.0):
    return seabed_pixels(rows=rows, cols=cols, range0_m=0.0, dr_m=DR, altitude_m=H, rng=rng, k_order=k_order)


def maps_of(p: Placement, rows, cols, sim=SimulationSettings(), sensor=SensorSettings(), range0_m=0.0):
    """The proportion maps the injector blends (same public pipeline: trace, then beam)."""
    m = place(p.mesh if p.mesh is not None else builtin_mesh(p.shape), along_m=p.row * DX, range_m=p.range_m,
              heading_deg=p.heading_deg)
    sig = trace(m, range0_m=range0_m, dr_m=DR, dx_m=DX, rows=rows, cols=cols, altitude_m=H, subrays=sim.subrays)
    return blur_along_track(sig, along_track_kernel(p.range_m, dx_m=DX, sensor=sensor), rows)


def test_contrast_matches_the_model(rng):
    """Done-criterion: on injected targets the mean shadow and echo gray levels divided by
    the local background match the model's ratios within 10 %."""
    host = host_tile(rng, rows=2500)
    rows, cols = host.shape
    mesh = box(3.0, 1.0, 0.6)
    model = SonarModel.from_settings()
    rho_s, rho_e = model.ratios(DR * np.arange(cols), H)
    ec_meas, ec_model = [], []
    for r in (30.0, 55.0, 80.0):
        pl = [Placement("box", row=row, range_m=r, heading_deg=0.0, mesh=mesh) for row in range(60, 2500, 120)]
        out, tg = inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, placements=pl, rng=rng)
        assert len(tg) == len(pl) == 21
        sh_meas, sh_model = [], []
        for p, t in zip(pl, tg):
            sig = maps_of(p, rows, cols)
            r0, r1, c0, c1 = sig.footprint
            assert t.footprint == sig.footprint
            o = out[r0:r1, c0:c1].astype(np.float64)
            # local background: the host (before injection) at the same ranges, over the tile
            bg = host[:, c0:c1].astype(np.float64).mean(axis=0)
            pure = (sig.p_shadow >= 0.999) & (sig.echo == 0)
            sh_meas.append((o / bg)[pure])
            sh_model.append(np.broadcast_to(rho_s[c0:c1], o.shape)[pure])
            bright = sig.echo >= 0.25 * sig.echo.max()
            ec_meas.append((o / bg)[bright])
            ec_model.append((sig.p_seabed + sig.p_shadow * rho_s[c0:c1] + rho_e[c0:c1] * sig.echo)[bright])
        sm, smod = np.concatenate(sh_meas), np.concatenate(sh_model)
        assert sm.size > 3000
        # Per-pixel ratios measured / model average to 1 (unit-mean exponential speckle).
        assert np.mean(sm / smod) == pytest.approx(1.0, rel=0.10)
        assert sm.mean() == pytest.approx(smod.mean(), rel=0.10)
    em, emod = np.concatenate(ec_meas), np.concatenate(ec_model)
    assert em.size > 3000
    assert np.mean(em / emod) == pytest.approx(1.0, rel=0.10)
    # and the echo really stands out, by about rho_echo * e
    assert em.mean() > 10.0


def test_truth_anchor_and_footprint(rng):
    host = host_tile(rng, rows=300, cols=800)
    pl = [Placement("box", row=100.4, range_m=40.0, mesh=box(2.0, 1.0, 0.5)),
          Placement("box", row=220.0, range_m=65.0, mesh=box(2.0, 1.0, 0.5))]
    out, tg = inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, placements=pl, rng=rng)
    for p, t in zip(pl, tg):
        assert t.row == round(p.row)
        far_edge = int(np.floor((p.range_m + 0.5 + DR / 2) / DR))  # first column behind the box
        assert abs(t.col - far_edge) <= 1
        assert t.range_m == p.range_m and t.shape == "box"
    changed = out != host
    inside = np.zeros_like(changed)
    for t in tg:
        r0, r1, c0, c1 = t.footprint
        inside[r0:r1, c0:c1] = True
    assert changed.any() and not (changed & ~inside).any()


def test_nan_untouched_and_outside_changes_nothing(rng):
    host = host_tile(rng, rows=200, cols=600)
    host[:, 300:305] = np.nan  # a no-data band through the target
    host[90:95, :] = np.nan    # and a ping drop-out
    pl = [Placement("cylinder", row=100, range_m=30.0, heading_deg=80.0)]
    out, tg = inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, placements=pl, rng=rng)
    assert len(tg) == 1
    np.testing.assert_array_equal(np.isnan(out), np.isnan(host))
    out2, tg2 = inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, rng=rng,
                               placements=[Placement("cylinder", row=100, range_m=300.0),
                                           Placement("cylinder", row=-500, range_m=30.0)])
    assert tg2 == [] and np.array_equal(out2, host, equal_nan=True)


def test_random_targets_apart_and_inside(rng):
    host = host_tile(rng, rows=1200, cols=600)
    tmpl = TemplateSettings()
    out, tg = inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, n_targets=12, rng=rng,
                             template=tmpl, range_span_m=(5.0, 55.0))
    assert 8 <= len(tg) <= 12
    gap_r = int(np.ceil(tmpl.context_factor * tmpl.length_m / DX / 2))
    for a in tg:
        r0, r1, c0, c1 = a.footprint
        assert r0 >= gap_r and r1 <= host.shape[0] - gap_r and c0 >= 1 and c1 <= host.shape[1] - 1
        assert 5.0 <= a.range_m <= 55.0 and a.shape in ("cylinder", "cone", "wedge", "sphere")
        assert r0 <= a.row < r1 and c0 <= a.col < c1
        for b in tg:
            if a is not b:
                q0, q1, d0, d1 = b.footprint
                assert not (r0 < q1 + gap_r and q0 < r1 + gap_r and c0 < d1 and d0 < c1)
    # the same seed gives the same result
    again = inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, n_targets=12,
                           rng=np.random.default_rng(7), template=tmpl, range_span_m=(5.0, 55.0))
    again2 = inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, n_targets=12,
                            rng=np.random.default_rng(7), template=tmpl, range_span_m=(5.0, 55.0))
    assert again[1] == again2[1] and np.array_equal(again[0], again2[0])


def test_amplitude_tiles_and_extremes(rng):
    amp = np.sqrt(host_tile(rng, rows=200, cols=600)).astype(np.float32)
    out, tg = inject_targets(amp, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, kind="amplitude", rng=rng,
                             placements=[Placement("sphere", row=100, range_m=40.0)])
    assert len(tg) == 1 and np.all(np.isfinite(out)) and out.min() >= 0
    # SPEC 8 extremes: all-NaN (no room), all-zero and 1e-6..1e6 tiles stay finite.
    nan = np.full((200, 600), np.nan, dtype=np.float32)
    o, t = inject_targets(nan, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, n_targets=3, rng=rng)
    assert t == [] and np.isnan(o).all()
    for tile in (np.zeros((200, 600), np.float32),
                 (10.0 ** rng.uniform(-6, 6, (200, 600))).astype(np.float32)):
        o, t = inject_targets(tile, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, rng=rng,
                              placements=[Placement("cone", row=100, range_m=30.0)])
        assert len(t) == 1 and np.all(np.isfinite(o))
    with pytest.raises(GeometryError):
        inject_targets(amp, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=0.0, rng=rng, n_targets=1)
    with pytest.raises(GeometryError):
        inject_targets(amp, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, rng=rng, n_targets=1, kind="dB")


def test_sas_beam_kernel():
    sas = SensorSettings()
    k30 = along_track_kernel(30.0, dx_m=DX, sensor=sas)
    k90 = along_track_kernel(90.0, dx_m=DX, sensor=sas)
    assert k30.sum() == pytest.approx(1.0) and np.allclose(k30, k30[::-1])
    np.testing.assert_allclose(k30, k90, atol=1e-3)  # Q_SAS: the same resolution at every range
    real = SensorSettings(sas=False)
    w = [np.sum(along_track_kernel(r, dx_m=DX, sensor=real) > 0.5 * along_track_kernel(r, dx_m=DX, sensor=real).max())
         for r in (40.0, 120.0)]
    assert w[1] / w[0] == pytest.approx(3.0, rel=0.35)  # physical beam lambda r / L_R grows with r


def test_background_curve_against_direct_mean(rng):
    a = rng.exponential(1.0, (50, 40)).astype(np.float32)
    a[3:9, 5] = np.nan
    a[:, 7] = np.nan
    g = background_curve(a, smooth_cols=1)
    ref = np.array([np.mean([x for x in a[:, j].astype(np.float64) if x == x]) if np.any(a[:, j] == a[:, j])
                    else np.nan for j in range(40)])
    np.testing.assert_allclose(g, ref, rtol=1e-12, equal_nan=True)
    g3 = background_curve(a, smooth_cols=3)
    j = 20
    v = a[:, j - 1:j + 2].astype(np.float64)
    assert g3[j] == pytest.approx(np.nanmean(v), rel=1e-12)


def test_injection_into_a_real_sas_texture(real_data, rng):
    """A real SAS seabed (SASSED crop, NSWC Panama City; 8-bit display amplitude, 0 = no data;
    pixel size not stated, taken as 10 cm, ranges from 20 m): the hidden pixels turn dark and
    the echo pixels bright against the real local seabed, whatever the aspect; nothing else
    changes."""
    import cv2

    path = real_data / "sas_textures" / "image_3_original_crop.png"
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img is not None, path
    amp = img.astype(np.float32)
    amp[img == 0] = np.nan
    rows, cols = amp.shape
    pl = [Placement("cylinder", row=80, range_m=30.0, heading_deg=0.0),
          Placement("wedge", row=200, range_m=45.0, heading_deg=90.0),       # end-on: a small shadow
          Placement("cylinder", row=320, range_m=60.0, heading_deg=45.0)]
    out, tg = inject_targets(amp, range0_m=20.0, dr_m=DR, dx_m=DX, altitude_m=H, placements=pl, rng=rng,
                             kind="amplitude")
    assert len(tg) == 3
    changed = ~np.isclose(out, amp, equal_nan=True)
    inside = np.zeros_like(changed)
    for p, t in zip(pl, tg):
        sig = maps_of(p, rows, cols, range0_m=20.0)
        r0, r1, c0, c1 = sig.footprint
        inside[r0:r1, c0:c1] = True
        o, h = out[r0:r1, c0:c1], amp[r0:r1, c0:c1]
        local = np.nanmean(h)
        hidden = (sig.p_shadow >= 0.95) & (sig.echo < 0.01)  # the beam leaks a little echo along-track
        bright = sig.echo >= 0.25 * sig.echo.max()
        assert hidden.sum() >= 20 and bright.sum() >= 5
        assert np.nanmean(o[hidden]) < 0.4 * local           # amplitude ratio ~ sqrt(rho_shadow) ~ 0.2
        assert np.nanmean(o[bright]) > 2.0 * local
    assert not (changed & ~inside).any()


@pytest.mark.parametrize("max_tries", [1, 30])
def test_swath_end_lets_shadows_run_off_the_far_edge(rng, max_tries):
    """The calibration injects into whole tiles, whose last column is where the sonar stops
    recording: with ``swath_end`` the draws refused only there are placed too, each losing the
    part of its shadow beyond (a real target's is cut there too), after the targets placed
    without it, which stay exactly what they were (same draws, same pixels)."""
    host = host_tile(rng, rows=1200, cols=600)  # swath 0-60 m
    kw = dict(range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, n_targets=8, template=TemplateSettings(),
              range_span_m=(50.0, 59.5), max_tries=max_tries)
    gen_c, gen_o = np.random.default_rng(3), np.random.default_rng(3)
    out_c, closed = inject_targets(host, rng=gen_c, **kw)
    out_o, opened = inject_targets(host, rng=gen_o, swath_end=True, **kw)
    assert gen_c.bit_generator.state == gen_o.bit_generator.state  # the caller's stream goes on unchanged
    cols = host.shape[1]
    assert all(t.footprint[3] <= cols - 1 for t in closed)
    assert opened[:len(closed)] == closed
    cut = opened[len(closed):]
    assert cut and all(t.footprint[3] == cols for t in cut), [t.footprint for t in opened]
    assert all(t.cut for t in cut) and not any(t.cut for t in closed)
    for t in opened:
        assert 50.0 <= t.range_m <= 59.5 and 0 <= t.col < cols
    # the extra targets changed nothing outside their footprints, and overlap nothing
    outside = np.ones(host.shape, bool)
    for t in cut:
        outside[t.footprint[0]:t.footprint[1], t.footprint[2]:t.footprint[3]] = False
    np.testing.assert_array_equal(out_o[outside], out_c[outside])
    fps = [t.footprint for t in opened]
    for i, a in enumerate(fps):
        for b in fps[i + 1:]:
            assert a[1] <= b[0] or b[1] <= a[0] or a[3] <= b[2] or b[3] <= a[2], (a, b)
    # a cut target's shadow is there, up to the edge: the pixels behind its echo darken
    t = cut[0]
    r0, r1, c0, c1 = t.footprint
    assert np.nanmean(out_o[r0:r1, t.col + 1:cols]) < np.nanmean(host[r0:r1, t.col + 1:cols])
