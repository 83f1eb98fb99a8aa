"""Send a live node's new and updated contacts over serial as SonarWiz $EXWPT sentences, so a
topside console shows them without our software.

    atr-node exwpt --from tcp://127.0.0.1:5560 --port /dev/ttyUSB0 --baudrate 9600
    atr-node exwpt --from tcp://127.0.0.1:5560 --port socket://topside:4001 --depth-m 23

Sentence (docs/operators.md): $EXWPT,<category>,<hh:mm:ss.sss>,<lon>,<lat>,<depth>,M,
ATR <id> <state> bel <Bel(T)>*<checksum>; category 3 = submerged mine by default. An update is
sent when the contact moved --min-move-m or its belief changed --min-bel-change; withdrawn
contacts only with --send-withdrawn. Sentences wait while the port is down and go out when it
is back. Started while the node runs, it first sends the live contacts of the node's snapshot
endpoint (ICD v1.1; --snapshot, by default the port after --from). Stops on Ctrl-C / SIGTERM, after --duration, or after --until-silent seconds of silence.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from ._follow import add_curve_arguments, add_snapshot_argument, curve_from_args, follow_endpoint, snapshot_from_args

EXIT_DETAIL = "exwpt: 1 also when sentences are still queued at the end (the serial port stayed down)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--from", dest="endpoint", metavar="ENDPOINT",
                        help="the node's PUB endpoint (default: links.publish_endpoint of --config)")
    parser.add_argument("--config", metavar="FILE", help="TOML settings, for the default endpoint")
    parser.add_argument("--port", required=True, metavar="URL",
                        help="serial device or pyserial URL: /dev/ttyUSB0, socket://host:port, loop://")
    parser.add_argument("--baudrate", type=int, default=9600, help="line speed (default 9600)")
    parser.add_argument("--category", type=int, default=3, choices=range(5), metavar="0-4",
                        help="SonarWiz contact category: 0 default, 1 unknown, 2 surface mine, "
                             "3 submerged mine (default), 4 wreck")
    parser.add_argument("--depth-m", type=float, metavar="M", help="water depth to report (default: null field)")
    parser.add_argument("--min-move-m", type=float, default=0.5, help="update when moved this far (default 0.5)")
    parser.add_argument("--min-bel-change", type=float, default=0.02,
                        help="update when Bel(T) changed this much (default 0.02)")
    parser.add_argument("--send-withdrawn", action="store_true", help="also send withdrawn contacts")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    parser.add_argument("--until-silent", type=float, metavar="S", help="stop when the node was silent S seconds")
    add_snapshot_argument(parser)
    add_curve_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ..config import load_settings
    from ..operators.exwpt import ExwptOutput
    from ..operators.stream import NodeFollower

    settings = None if args.endpoint else load_settings(args.config)
    endpoint = follow_endpoint(args, settings)
    snapshot = snapshot_from_args(args, settings)
    out = ExwptOutput(args.port, baudrate=args.baudrate, category=args.category, depth_m=args.depth_m,
                      min_move_m=args.min_move_m, min_bel_change=args.min_bel_change,
                      send_withdrawn=args.send_withdrawn)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        with NodeFollower(endpoint, on_contact=out.offer, curve=curve_from_args(args), snapshot=snapshot,
                          snapshot_timeout_s=args.snapshot_timeout) as follower:
            announce = follower.announcer("atr-node exwpt")

            def tick() -> None:
                announce()
                out.flush()  # what waited for a port that was down

            try:
                why = follower.follow(duration_s=args.duration, until_silent_s=args.until_silent, stop=stop,
                                      tick=tick)
            except KeyboardInterrupt:
                why = "interrupt"
            out.flush()
    finally:
        out.close()
    s = out.stats
    print(f"atr-node exwpt: stopped ({why}); {s.offered} contact messages, {s.sent} sentences sent "
          f"({s.bytes_sent} bytes), {s.skipped_small} small updates and {s.skipped_withdrawn} withdrawals not sent, "
          f"{s.write_errors} write errors, {out.pending} still queued", file=sys.stderr)
    return 0 if out.pending == 0 else 1
