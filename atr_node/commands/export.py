"""Export the contact list to GeoJSON, KML or CSV, from a live node or a --contacts-out file.

From a file (``atr-node replay --contacts-out FILE``)::

    atr-node export --contacts contacts.jsonl -o contacts.geojson -o contacts.kml -o contacts.csv

From a live node (its PUB endpoint, ICD section 3): the node's live contacts when the export
started (its snapshot endpoint, ICD v1.1: --snapshot, by default the port after --from) and
those published while following, latest state per id, written when the node falls silent (--until-silent, default 5 s), after
--duration, or on Ctrl-C; with --refresh S the files are also rewritten every S seconds (point
Google Earth's network link or QGIS at them)::

    atr-node export --from tcp://127.0.0.1:5560 -o live.kml --refresh 10

The format comes from each file's suffix (.geojson/.json, .kml, .csv) or --format. Withdrawn
contacts are left out unless --include-withdrawn (then flagged by their 'state' property).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time

from ..errors import AtrError, describe
from ._follow import add_curve_arguments, add_snapshot_argument, curve_from_args, follow_endpoint, snapshot_from_args

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--contacts", metavar="FILE", help="JSON lines of final contacts (replay --contacts-out)")
    src.add_argument("--from", dest="endpoint", metavar="ENDPOINT",
                     help="a live node's PUB endpoint, e.g. tcp://127.0.0.1:5560")
    parser.add_argument("-o", "--out", metavar="FILE", action="append", required=True,
                        help="output file (repeatable); format from the suffix: .geojson .json .kml .csv")
    parser.add_argument("--format", choices=("geojson", "kml", "csv"), help="format of every -o (default: suffix)")
    parser.add_argument("--include-withdrawn", action="store_true", help="also export withdrawn contacts")
    parser.add_argument("--duration", type=float, metavar="S", help="live: follow for S seconds at most")
    parser.add_argument("--until-silent", type=float, default=5.0, metavar="S",
                        help="live: stop when the node sent nothing for S seconds (default 5; 0 = never)")
    parser.add_argument("--refresh", type=float, metavar="S", help="live: rewrite the files every S seconds too")
    add_snapshot_argument(parser)
    add_curve_arguments(parser)


def _write(args: argparse.Namespace, book) -> int:
    from ..operators.export import write_export

    contacts = book.contacts(include_withdrawn=args.include_withdrawn)
    for path in args.out:
        write_export(path, contacts, fmt=args.format)
    return len(contacts)


def run(args: argparse.Namespace) -> int:
    from ..operators.book import read_contacts
    from ..operators.export import format_of
    from ..operators.stream import NodeFollower, snapshot_text

    for path in args.out:  # a bad suffix fails before any waiting
        format_of(path, args.format)
    if args.endpoint:
        follow_endpoint(args, None)
    if args.contacts:
        book = read_contacts(args.contacts)
        n = _write(args, book)
        print(f"atr-node export: {n} contacts from {args.contacts} -> {', '.join(args.out)}", file=sys.stderr)
        return 0
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with NodeFollower(args.endpoint, curve=curve_from_args(args), snapshot=snapshot_from_args(args),
                      snapshot_timeout_s=args.snapshot_timeout) as follower:
        last = [time.monotonic()]
        announce = follower.announcer("atr-node export")

        def tick() -> None:
            announce()
            if args.refresh and time.monotonic() - last[0] >= args.refresh and _heard(follower.stats):
                last[0] = time.monotonic()
                try:
                    _write(args, follower.book)
                except AtrError as exc:  # keep following: the next refresh or the final write retries
                    log.warning("refresh failed: %s", describe(exc))

        try:
            why = follower.follow(duration_s=args.duration, until_silent_s=args.until_silent or None, stop=stop,
                                  tick=tick)
        except KeyboardInterrupt:
            why = "interrupt"
        st = follower.stats
        if not _heard(st):  # no file rather than empty ones that look like "no contacts"
            raise AtrError(f"nothing received from {args.endpoint}: is a node publishing there? (no file written)")
        n = _write(args, follower.book)
        print(f"atr-node export: {n} contacts ({follower.book.n_withdrawn} withdrawn) from {args.endpoint} after "
              f"{st.heartbeats} heartbeats, {st.contacts} contact messages, {st.bad} bad; {snapshot_text(st)}; "
              f"stopped: {why} -> {', '.join(args.out)}", file=sys.stderr)
    return 0


def _heard(stats) -> bool:
    """Whether the node was heard at all: a heartbeat, a contact message or a snapshot."""
    return bool(stats.heartbeats or stats.contacts or getattr(stats, "snapshot", "") == "ok")
