"""Score contacts against a truth CSV (ICD section 5) and draw ROC curves.

Three sources of contacts:

  --contacts FILE      the JSON lines of `atr-node replay --contacts-out` (final states)
  --subscribe ENDPOINT a live node's PUB socket, for --duration seconds (latest state per id)
  --log LOG            a recording: the node is run on it; its published contacts are scored
                       first, as --contacts scores them (and written to contacts.jsonl),
                       then, in a comparison pass recomputed from the node's detections,
                       every method of the paper's figure 6: each detector
                       alone, AND of the three best and of all four, OR of all four,
                       Dempster-Shafer fusion without missed-detection evidence, with it, and
                       with it plus the weakest detector

A contact matches a target within 3 m; each target matches at most one contact; the rest are
false alarms. ROC curves sweep the threshold on Bel(T). Writes a Markdown summary, roc.png (and
with --log the mosaic, belief map and P(y) figures) into --out.

--clutter CSV lists known objects that are not targets (rocks, debris, an earlier survey's
non-mine-like bottom objects), in the truth file's format with an optional target_like column
(1/0): the summary then says how many false alarms lie within 3 m of them, how many are second
contacts on a target, and how many lie on no known object; --log's mosaic shows them.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

from ..config import load_settings
from ._crs import add_crs_argument, add_frequency_argument, with_recording_options
from ..errors import AtrError
from ._endpoints import check_endpoint
from ..operators.book import read_contacts


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--truth", required=True, metavar="CSV", help="truth targets: lat_deg,lon_deg,shape[,...]")
    parser.add_argument("--clutter", metavar="CSV",
                        help="known objects that are not targets: lat_deg,lon_deg,shape[,target_like][,...]; "
                             "says what the false alarms lie on")
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
    add_crs_argument(parser)  # with --log: an XTF's positions in projected metres (ICD v1.1 section 6)
    add_frequency_argument(parser)


def run(args: argparse.Namespace) -> int:
    from ..evaluation.scoring import read_truth

    settings = with_recording_options(args, load_settings(args.config))  # the run reads them from the settings
    crs = settings.recording.crs
    # every input checked before the output folder exists: a failure leaves nothing behind
    read_truth(args.truth)
    if args.clutter:
        from ..evaluation.scoring import read_clutter

        read_clutter(args.clutter)
    if args.bel is not None and not 0.0 <= args.bel <= 1.0:
        raise AtrError(f"--bel {args.bel:g}: expected a threshold on Bel(T) in [0, 1]")
    if args.log:
        from ._inputs import require_sonar_tile

        require_sonar_tile(args.log, crs=crs, frequency=settings.recording.frequency)
    elif args.contacts:
        read_contacts(args.contacts)  # one line on a bad file, before --out exists
    else:
        check_endpoint(args.subscribe, "--subscribe")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise AtrError(f"--out {out}: not a folder")
    created = not out.exists()
    try:
        return _evaluate(args, settings, out)
    except BaseException:
        if created:  # made by this run: whatever is in it is partial
            shutil.rmtree(out, ignore_errors=True)
        raise


def _evaluate(args: argparse.Namespace, settings, out: Path) -> int:
    from ..evaluation.scoring import read_clutter, read_truth, score_contacts

    out.mkdir(parents=True, exist_ok=True)
    bel = args.bel if args.bel is not None else settings.fusion.report_bel
    clutter = read_clutter(args.clutter) if args.clutter else None
    if args.log:
        from ..evaluation.evaluate import evaluate_log, rows_markdown
        from .replay import build_model

        model, online = build_model(settings, args.model, args.online_calibration, deterministic=True)
        res = evaluate_log(settings, args.log, args.truth, out, model=model, online=online, name=Path(args.log).stem,
                           clutter=clutter)
        text = f"# Evaluation of {args.log}\n\n{res.targets} targets, {res.covered_km2:.4f} km² covered.\n\n"
        if clutter is not None:
            text += f"The node, as published: {res.stats['node_false_alarm_anatomy_text']}.\n\n"
        if res.stats.get("navigation_report"):  # do the legs agree? (fusion.navcheck)
            text += f"{res.stats['navigation_report'][0].upper()}{res.stats['navigation_report'][1:]}.\n\n"
        text += rows_markdown(res.rows) + "\n\n" + "\n".join(
            f"- claim {k}: **{'holds' if ok else 'does not hold'}** ({why})" for k, (ok, why) in res.claims.items())
        (out / "evaluation.md").write_text(text + "\n")
        print(text)
        return 0
    if args.contacts:
        # every contact's final message, the withdrawn ones too (scoring keeps what it counts)
        contacts = read_contacts(args.contacts).contacts(include_withdrawn=True)
    else:
        contacts = _listen(args.subscribe, args.duration)
    # the same scoring as the demo's node row (one function, atr_node.evaluation.scoring)
    score = score_contacts(contacts, read_truth(args.truth), bel=bel, clutter=clutter)
    curve, p, summary = score.curve, score.point, score.summary()
    (out / "evaluation.json").write_text(json.dumps(summary, indent=2))
    try:
        from ..evaluation.report import plot_roc

        # the node's contacts are its fusion's output: the fusion panel (the only one here)
        plot_roc([], [], out / "roc.png", covered_km2=0.0, title="node contacts: ROC on Bel(T)", fused=[curve])
    except ImportError:
        print("matplotlib not installed: no roc.png (pip install 'atr-node[plots]')", file=sys.stderr)
    print(f"{score.targets} targets, {score.contacts} contacts: at Bel >= {bel:g}, Pd {p.pd:.2f} "
          f"({p.matched} matched), {p.false_alarms} false alarms; best Pd {summary['best_pd']:.2f} "
          f"with {summary['fa_at_best_pd']:g} false alarms")
    if score.anatomy is not None:
        line = score.anatomy_line()
        print(line[:1].upper() + line[1:])
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
