"""PNG gallery of simulated target signatures: every built-in shape at near, mid and far range.

Each panel is a target injected with :func:`atr_node.simulation.inject_targets` into a
synthetic K-distributed seabed (default settings: 120 kHz SAS, 14 m altitude, 10 cm pixels),
displayed in dB over 40 dB with the sonar on the left (range increases to the right). The
truth anchor (echo/shadow boundary) is marked with a small cross.

    python tools/figures/gallery_signatures.py --out gallery.png [--quick] [--seabed sand] [--heading 30]
"""

from __future__ import annotations

import argparse
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from atr_node.config import SimulationSettings  # noqa: E402
from atr_node.simulation.inject import Placement, inject_targets  # noqa: E402
from atr_node.simulation.meshes import BUILTIN_SHAPES  # noqa: E402
from atr_node.simulation.seabed import seabed_pixels  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="signature_gallery.png", help="PNG file to write")
    ap.add_argument("--ranges", default="8,35,90", help="near,mid,far ground ranges in metres")
    ap.add_argument("--heading", type=float, default=20.0, help="target heading from along-track (deg)")
    ap.add_argument("--seabed", default="silt", choices=("mud", "silt", "sand", "gravel", "rock"))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="two ranges, smaller panels")
    args = ap.parse_args(argv)
    ranges = [float(r) for r in args.ranges.split(",")]
    if args.quick:
        ranges = ranges[:2]
    sim = SimulationSettings(seabed=args.seabed)
    rng = np.random.default_rng(args.seed)
    half_w, half_h = 60, 40  # panel half-size in pixels (6 m x 8 m)
    fig, axes = plt.subplots(len(BUILTIN_SHAPES), len(ranges), figsize=(3.2 * len(ranges), 2.3 * len(BUILTIN_SHAPES)),
                             squeeze=False)
    for j, r in enumerate(ranges):
        r0 = max(r - 10.0, 0.0)
        px = seabed_pixels(rows=2 * half_h + 40, cols=300, range0_m=r0, dr_m=0.1, altitude_m=14.0, rng=rng)
        for i, shape in enumerate(BUILTIN_SHAPES):
            out, tg = inject_targets(px, range0_m=r0, dr_m=0.1, dx_m=0.1, altitude_m=14.0, rng=rng, simulation=sim,
                                     placements=[Placement(shape, row=px.shape[0] / 2, range_m=r,
                                                           heading_deg=args.heading)])
            c = int(round((r - r0) / 0.1))
            c0, c1 = max(c - half_w // 2, 0), c + 3 * half_w // 2
            rr0, rr1 = px.shape[0] // 2 - half_h, px.shape[0] // 2 + half_h
            db = 10 * np.log10(np.maximum(out[rr0:rr1, c0:c1], 1e-6))
            ref = np.nanmedian(10 * np.log10(np.maximum(px, 1e-6)))
            ax = axes[i, j]
            ax.imshow(db, cmap="copper", vmin=ref - 15, vmax=ref + 25, aspect="equal",
                      extent=(r0 + c0 * 0.1, r0 + c1 * 0.1, rr1 * 0.1 - rr0 * 0.1, 0))
            if tg:
                t = tg[0]
                ax.plot(r0 + t.col * 0.1, (t.row - rr0) * 0.1, "c+", ms=8)
            ax.set_title(f"{shape} at {r:.0f} m", fontsize=8)
            ax.tick_params(labelsize=6)
    fig.suptitle(f"simulated signatures (seabed {args.seabed}, H = 14 m, heading {args.heading:.0f} deg; "
                 "range -> right, along-track down, metres)", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
