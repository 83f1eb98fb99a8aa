#!/usr/bin/env python3
"""Keep one CPU core busy, for a bounded time: the load under which CI runs the test suite.

Issue 20: the suite must pass on a machine doing other work, so ``.ci/run`` starts this in the
background (and kills it by a trap at exit). It spins in pure Python (one core, no memory)
until ``--max-s`` seconds have passed or its parent process has gone, so a CI job that dies
without running its trap does not leave the load behind for long.

Examples
--------
    python tools/soak/busy_core.py --max-s 60        # one core busy for a minute
    python tools/soak/busy_core.py &                 # in a script; kill it when done
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def spin(max_s: float, parent_pid: int, check_every_s: float = 1.0) -> int:
    """Busy-loop until ``max_s`` seconds have passed or ``parent_pid`` is no longer our parent.

    Parameters
    ----------
    max_s : float
        Upper bound of the run, seconds.
    parent_pid : int
        The process that started us; when we are re-parented (it died), we stop.
    check_every_s : float
        How often the clock and the parent are looked at, seconds.

    Returns
    -------
    int
        Number of busy rounds done (one per ``check_every_s``), for the log.
    """
    t_end_s = time.monotonic() + max_s
    rounds = 0
    while time.monotonic() < t_end_s and os.getppid() == parent_pid:
        t_next_s = time.monotonic() + check_every_s
        x = 0
        while time.monotonic() < t_next_s:
            for i in range(10_000):  # pure-Python arithmetic: holds the GIL and one core, no memory
                x += i * i
        rounds += 1
    return rounds


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--max-s", type=float, default=3600.0,
                    help="stop after this many seconds at the latest (default 3600)")
    args = ap.parse_args(argv)
    if not args.max_s > 0:
        print(f"busy_core: --max-s must be > 0, got {args.max_s}", file=sys.stderr)
        return 2
    rounds = spin(args.max_s, os.getppid())
    print(f"busy_core: stopped after {rounds} s busy", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
