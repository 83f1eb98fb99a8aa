"""Score contacts against a truth CSV (ICD section 5) and draw ROC curves.

Three sources of contacts:

  --contacts FILE      the JSON lines of `atr-node replay --contacts-out` (final states)
  --subscribe ENDPOINT a live node's PUB socket, for --duration seconds (latest state per id)
  --log LOG            a recording: the node's pipeline is run on it once and every method of
                       the paper's figure 6 is scored on the same detections: each detector
                       alone, AND of the three best and of all four, OR of all four,
                       Dempster-Shafer fusion without missed-detection evidence, with it, and
                       with it plus the weakest detector

A contact matches a target within 3 m; each target matches at most one contact; the rest are
false alarms. ROC curves sweep the threshold on Bel(T). Writes a Markdown summary, roc.png (and
with --log the mosaic, belief map and P(y) figures) into --out.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from ..config import load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--truth", required=True, metavar="CSV", help="truth targets: lat_deg,lon_deg,shape[,...]")
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--contacts", metavar="FILE", help="contacts as JSON lines (--contacts-out of replay)")
    src.add_argument("--subscribe", metavar="ENDPOINT", help="a live node's PUB endpoint")
    src.add_argument("--log", metavar="LOG", help="a recording: run the node and compare every method")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds to listen with --subscribe (default 60)")
    parser.add_argument("--config", metavar="FILE", help="TOML settings (with --log)")
    parser.add_argument("--model", metavar="FILE", help="performance model (with --log; default: shipped)")
    parser.add_argument("--online-calibration", choices=("on", "off"), default="on",
                        help="with --log: calibrate on-line from the first tiles (default on)")
    parser.add_argument("--out", metavar="DIR", default="evaluation", help="output folder (default ./evaluation)")
    parser.add_argument("--bel", type=float, help="reporting threshold on Bel(T) (default fusion.report_bel)")


def run(args: argparse.Namespace) -> int:
    from ..evaluation.scoring import contacts_from_jsonl, local_en, read_truth, roc

    settings = load_settings(args.config)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    bel = args.bel if args.bel is not None else settings.fusion.report_bel
    if args.log:
        from ..evaluation.evaluate import evaluate_log, rows_markdown
        from .replay import build_model

        model, online = build_model(settings, args.model, args.online_calibration, deterministic=True)
        res = evaluate_log(settings, args.log, args.truth, out, model=model, online=online, name=Path(args.log).stem)
        text = f"# Evaluation of {args.log}\n\n{res.targets} targets, {res.covered_km2:.4f} km² covered.\n\n"
        text += rows_markdown(res.rows) + "\n\n" + "\n".join(
            f"- claim {k}: **{'holds' if ok else 'does not hold'}** ({why})" for k, (ok, why) in res.claims.items())
        (out / "evaluation.md").write_text(text + "\n")
        print(text)
        return 0
    if args.contacts:
        contacts = contacts_from_jsonl(args.contacts)
    else:
        contacts = _listen(args.subscribe, args.duration)
    truth = read_truth(args.truth)
    live = [c for c in contacts if c.get("state") != "withdrawn"]
    if truth:
        lat0, lon0 = truth[0].lat_deg, truth[0].lon_deg
    elif live:
        lat0, lon0 = live[0]["lat_deg"], live[0]["lon_deg"]
    else:
        lat0, lon0 = 0.0, 0.0
    t_en = np.column_stack(local_en(np.array([t.lat_deg for t in truth]), np.array([t.lon_deg for t in truth]),
                                    lat0, lon0)) if truth else np.zeros((0, 2))
    c_en = np.column_stack(local_en(np.array([c["lat_deg"] for c in live]), np.array([c["lon_deg"] for c in live]),
                                    lat0, lon0)) if live else np.zeros((0, 2))
    curve = roc("node contacts", c_en, [c["bel"] for c in live], t_en)
    p = curve.at_threshold(bel)
    summary = {"targets": len(truth), "contacts": len(live), "threshold_bel": bel, "pd": p.pd,
               "false_alarms": p.false_alarms, "matched": p.matched, "best_pd": curve.best_pd(),
               "fa_at_best_pd": curve.fa_at_pd(curve.best_pd())}
    (out / "evaluation.json").write_text(json.dumps(summary, indent=2))
    try:
        from ..evaluation.report import plot_roc

        plot_roc([curve], [], out / "roc.png", covered_km2=0.0, title="node contacts: ROC on Bel(T)")
    except ImportError:
        print("matplotlib not installed: no roc.png (pip install 'atr-node[plots]')", file=sys.stderr)
    print(f"{len(truth)} targets, {len(live)} contacts: at Bel >= {bel:g}, Pd {p.pd:.2f} "
          f"({p.matched} matched), {p.false_alarms} false alarms; best Pd {curve.best_pd():.2f} "
          f"with {curve.fa_at_pd(curve.best_pd()):g} false alarms")
    return 0


def _listen(endpoint: str, duration: float) -> list[dict]:
    from ..node.publisher import Subscriber
    from ..node.wire import validate_contact

    sub = Subscriber(endpoint, topics=(b"contact",))
    latest: dict[int, dict] = {}
    end = time.monotonic() + duration
    try:
        while time.monotonic() < end:
            got = sub.recv(timeout_s=min(0.5, max(end - time.monotonic(), 0.01)))
            if got is None:
                continue
            _, msg = got
            if not validate_contact(msg):
                latest[msg["id"]] = msg
    except KeyboardInterrupt:
        pass
    finally:
        sub.close()
    return list(latest.values())
