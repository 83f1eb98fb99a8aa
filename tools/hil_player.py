#!/usr/bin/env python3
"""Hardware-in-the-loop: play a recording OUT onto a pty, a CAN bus and a ZeroMQ socket.

The node under test then runs on its ordinary live links, configured as printed at start::

    [links]
    nmea_url = "/dev/pts/N"             (the pty created here)
    can_interface = "virtual"           (or the interface given)
    can_channel = "atr-hil"
    sonar_endpoint = "tcp://127.0.0.1:5550"  (PULL; --sonar-socket pub -> "sub")

SOURCE is anything ``hw.open_link`` opens as a recording: ``mission.atrlog``,
``replay:/path.atrlog``, ``stamped:/path/to/nmea.txt``, ``candump:/path/candump.log``.
Example: ``python tools/hil_player.py mission.atrlog --speed 2``; Ctrl-C stops.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import hw  # noqa: E402
from hw.hil import CanBusOut, HilPlayer, PtyNmeaOut, ZmqTileOut  # noqa: E402


def parse_speed(text: str) -> float | None:
    if text.lower() in ("max", "inf"):
        return None
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"speed {text!r}: expected a factor > 0 or 'max'")
    return value


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("source", help="recording: .atrlog, replay:PATH, stamped:PATH or candump:PATH")
    ap.add_argument("--speed", type=parse_speed, default=1.0, help="factor (1 = real time) or 'max' (default 1)")
    ap.add_argument("--max-gap-s", type=float, default=None, help="shorten recorded silences to this (log seconds)")
    ap.add_argument("--can-interface", default="virtual", help="python-can interface of the CAN output")
    ap.add_argument("--can-channel", default="atr-hil", help="channel of the CAN output")
    ap.add_argument("--sonar-endpoint", default="tcp://127.0.0.1:5550", help="endpoint bound by the tile output")
    ap.add_argument("--sonar-socket", choices=("push", "pub"), default="push")
    ap.add_argument("--no-nmea", action="store_true", help="do not create the pty (NMEA records skipped)")
    ap.add_argument("--no-can", action="store_true", help="do not open the CAN output")
    ap.add_argument("--no-sonar", action="store_true", help="do not bind the tile output")
    ap.add_argument("--max-records", type=int, default=None, help="stop after this many records")
    args = ap.parse_args(argv)

    source = hw.open_link(args.source, speed=args.speed, max_gap_s=args.max_gap_s)
    nmea = None if args.no_nmea else PtyNmeaOut()
    can_out = None if args.no_can else CanBusOut(args.can_interface, args.can_channel)
    sonar = None if args.no_sonar else ZmqTileOut(args.sonar_endpoint, socket=args.sonar_socket)
    print("configure the node under test with:\n[links]")
    if nmea:
        print(f'nmea_url = "{nmea.slave_path}"')
    if can_out:
        print(f'can_interface = "{args.can_interface}"\ncan_channel = "{args.can_channel}"')
    if sonar:
        print(f'sonar_endpoint = "{sonar.endpoint}"\nsonar_socket = "{"pull" if args.sonar_socket == "push" else "sub"}"')
    sys.stdout.flush()
    player = HilPlayer(source, nmea=nmea, can=can_out, sonar=sonar)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: source.shutdown())
    try:
        counts = player.run(max_records=args.max_records)
    except KeyboardInterrupt:
        counts = player.counts
    finally:
        player.close()
    print("played: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
