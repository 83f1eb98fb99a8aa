#!/usr/bin/env python3
"""Record one or more links to an ``.atrlog`` (ICD section 4), or convert recordings to one.

Each SPEC is anything ``hw.open_link`` opens: a serial URL (``/dev/ttyUSB0``, ``socket://h:p``),
``can://socketcan/can0``, a ZeroMQ endpoint (``tcp://127.0.0.1:5550``), or a recording
(``stamped:nmea.txt?speed=max``, ``candump:bus.log?speed=max``, ``replay:x.atrlog``).
Recording stops at Ctrl-C, after ``--seconds``, after ``--max-records``, or when every
source has ended (recordings). Recordings only are merged in time order; live links (or a
mix) are written in arrival order.

Example, converting the real R/V Palmer NMEA log and an NMEA 2000 candump into one log::

    python tools/record_links.py out.atrlog "stamped:nmea.txt?speed=max" "candump:can.log?speed=max"
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import hw  # noqa: E402
from hw.recorder import LinkMux, RecordingLink  # noqa: E402
from hw.replay import TimeMerge  # noqa: E402

RECORDINGS = ("replay:", "stamped:", "candump:")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path, help="the .atrlog to write")
    ap.add_argument("specs", nargs="+", metavar="SPEC", help="links to record")
    ap.add_argument("--seconds", type=float, default=None, help="stop after this many wall-clock seconds")
    ap.add_argument("--max-records", type=int, default=None, help="stop after this many records")
    args = ap.parse_args(argv)
    links = []
    try:
        for spec in args.specs:
            links.append(hw.open_link(spec))
    except hw.LinkError as exc:
        for link in links:
            link.shutdown()
        print(f"record_links: {exc}", file=sys.stderr)
        return 1
    if len(links) == 1:
        source = links[0]
    elif all(s.startswith(RECORDINGS) or s.endswith(".atrlog") for s in args.specs):
        source = TimeMerge(links)  # recordings: merged in time order
    else:
        source = LinkMux(links)  # live links: in arrival order
    end = None if args.seconds is None else time.monotonic() + args.seconds
    n = 0
    with RecordingLink(source, args.out, flush_every=100) as rec:
        try:
            while not rec.at_end and (end is None or time.monotonic() < end):
                if rec.recv(timeout=0.1) is not None:
                    n += 1
                    if args.max_records is not None and n >= args.max_records:
                        break
        except KeyboardInterrupt:
            pass
    counts = {l.name: dict(l.counts) for l in links}
    print(f"recorded {n} records to {args.out}; per link: {counts}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
