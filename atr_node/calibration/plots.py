"""The calibration's figures: confidence against gamma for three thresholds per detector (like
the paper's figure 3) and the P(y) curves of all detectors with Wilson bands (figure 4).

matplotlib is imported on first use, with the Agg backend (no display needed).
"""

from __future__ import annotations

import os
from pathlib import Path
import numpy as np

from ..config import CalibrationSettings
from .model import PerformanceModel
from .responses import Responses
from .stats import confidence_curve, dobeck_threshold


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def figure3_thresholds(x_t: np.ndarray, tau: float, x_n: np.ndarray | None = None, *,
                       pd_high: float = 0.8, cell_far: float = 0.01) -> list[float]:
    """Three operating points for figure 3, sorted: a low threshold that ``cell_far`` of the
    non-target cells exceed (where false alarms shape the confidence; Dobeck at Pd 0.99 when
    there are no cells), the model's tau, and Dobeck's threshold at Pd ``pd_high``."""
    fin_n = np.asarray([] if x_n is None else x_n, dtype=np.float64)
    fin_n = fin_n[np.isfinite(fin_n)]
    low = float(np.quantile(fin_n, 1.0 - cell_far)) if fin_n.size else dobeck_threshold(x_t, 0.99, default=tau)
    taus = {float(tau), low, dobeck_threshold(x_t, pd_high, default=tau)}
    return sorted(taus)


def plot_confidence(responses: Responses, model: PerformanceModel, path: str | os.PathLike[str], *,
                    calibration: CalibrationSettings) -> Path:
    """Confidence c_d(gamma; tau) of each detector for three thresholds (paper figure 3).

    The thresholds are those of :func:`figure3_thresholds`; the model's own (tau_d, Dobeck at
    the Pd target) is drawn thick.
    """
    plt = _pyplot()
    dets = [d for d in responses.detectors if d in model.detectors]
    ncol = 2 if len(dets) > 1 else 1
    nrow = (len(dets) + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.0 * ncol, 3.6 * nrow), squeeze=False)
    for ax, d in zip(axes.ravel(), dets):
        x_t, x_n = responses.target[d], responses.nontarget[d]
        tau_d = model.tau[d]
        taus = figure3_thresholds(x_t, tau_d, x_n)
        for tau in taus:
            c = confidence_curve(x_t, x_n, tau, prior_target=calibration.prior_target,
                                 n_points=calibration.confidence_points, smoothing=calibration.smoothing)
            pd = float(np.mean(x_t[np.isfinite(x_t)] > tau)) if np.isfinite(x_t).any() else float("nan")
            ax.plot(c.gamma, c.confidence, lw=2.5 if tau == tau_d else 1.2,
                    label=f"tau={tau:.3g} (Pd={pd:.2f})" + (" model" if tau == tau_d else ""))
        fin = x_t[np.isfinite(x_t)]
        if fin.size:
            # Up to the 95th percentile of the target responses: the sparse tail is flat anyway.
            hi = float(np.percentile(fin, 95))
            if hi > taus[0]:
                ax.set_xlim(taus[0] - 0.05 * (hi - taus[0]), hi)
                if taus[0] > 0 and hi / taus[0] > 20:
                    ax.set_xscale("log")
                    ax.set_xlim(taus[0] * 0.9, hi)
        ax.set_title(f"{d}: confidence P(T | gamma), prior {calibration.prior_target:g}")
        ax.set_xlabel("cluster max gamma")
        ax.set_ylabel("confidence")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    for ax in axes.ravel()[len(dets):]:
        ax.set_visible(False)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_pyr(model: PerformanceModel, path: str | os.PathLike[str]) -> Path:
    """P(y) curves of all detectors at their thresholds, with Wilson 95 % bands (figure 4)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for d, p in model.detectors.items():
        y = p.pyr
        c = y.centres_m
        line, = ax.plot(c, y.pd, marker="o", ms=3, label=f"{d} (tau={p.tau:.3g})")
        ax.fill_between(c, y.low, y.high, color=line.get_color(), alpha=0.15, lw=0)
    ax.set_xlabel("ground range (m)")
    ax.set_ylabel("P(detection)")
    ax.set_ylim(0, 1.02)
    ax.set_title("P(y) curves, Wilson 95 % bands; Pd = 0 outside the calibrated span")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
