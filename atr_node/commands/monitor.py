"""Live view of a node: heartbeat (tiles in/out, queue, latency, mode) and the contacts sorted
by belief, redrawn in place in the terminal.

    atr-node monitor --from tcp://127.0.0.1:5560
    atr-node monitor --from tcp://127.0.0.1:5560 --png belief.png --state-dir /var/lib/atr-node

--png FILE rewrites a belief-map PNG every --png-every seconds: contacts as circles of radius
sigma coloured by Bel(T); with --state-dir (the node's snapshot folder) over the real belief
map of the evidence grid, else over the extents of the contacts each leg saw. A monitor
started while the node runs shows the contacts published before it, from the node's snapshot
endpoint (ICD v1.1; --snapshot, by default the port after --from). Stops on Ctrl-C,
after --duration, or when the node was silent for --until-silent seconds (default: never).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from ._follow import add_curve_arguments, add_snapshot_argument, curve_from_args, follow_endpoint, snapshot_from_args
from ._progress import add_progress_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--from", dest="endpoint", metavar="ENDPOINT",
                        help="the node's PUB endpoint (default: links.publish_endpoint of --config)")
    parser.add_argument("--config", metavar="FILE", help="TOML settings, for the default endpoint")
    parser.add_argument("--refresh", type=float, default=0.5, metavar="S", help="redraw period (default 0.5 s)")
    parser.add_argument("--rows", type=int, metavar="N", help="contact rows shown (default: fit the terminal)")
    parser.add_argument("--png", metavar="FILE", help="also keep a belief-map PNG up to date")
    parser.add_argument("--png-every", type=float, default=5.0, metavar="S", help="PNG period (default 5 s)")
    parser.add_argument("--state-dir", metavar="DIR", help="the node's --state-dir: real belief map in the PNG")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    parser.add_argument("--until-silent", type=float, metavar="S", help="stop when the node was silent S seconds")
    add_progress_argument(parser, old=("--plain", "--quiet"),
                          help="no redraw in place (no ANSI escapes): print frames one after another")
    add_snapshot_argument(parser)
    add_curve_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ..config import load_settings
    from ..operators.monitor import Monitor
    from ..operators.stream import NodeFollower, snapshot_text

    settings = None if args.endpoint else load_settings(args.config)
    endpoint = follow_endpoint(args, settings)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with NodeFollower(endpoint, curve=curve_from_args(args), snapshot=snapshot_from_args(args, settings),
                      snapshot_timeout_s=args.snapshot_timeout) as follower:
        mon = Monitor(follower, out=sys.stdout, refresh_s=args.refresh, ansi=False if args.no_progress else None,
                      max_rows=args.rows, png=args.png, png_every_s=args.png_every, state_dir=args.state_dir)
        why = mon.run(duration_s=args.duration, until_silent_s=args.until_silent, stop=stop)
    print(f"atr-node monitor: stopped ({why}); {follower.stats.heartbeats} heartbeats, "
          f"{follower.stats.contacts} contact messages, {follower.stats.bad} bad; {snapshot_text(follower.stats)}"
          + (f"; {mon.pngs} PNG(s) written to {args.png}" if args.png else "")
          + (f"; PNG problem: {mon.png_error}" if mon.png_error else ""), file=sys.stderr)
    return 0
