"""The one switch that turns a command's progress display off: ``--no-progress``, the same
name in every command that shows progress (replay, calibrate, batch, demo, monitor). The
names some commands used before (``--quiet``, ``--plain``) stay accepted, hidden from
--help, so existing scripts keep working."""

from __future__ import annotations

import argparse

OLD_NAMES = ("--quiet",)


def add_progress_argument(parser: argparse.ArgumentParser, *, old: tuple[str, ...] = OLD_NAMES,
                          help: str = "no progress line on stderr (it is off anyway when stderr is not a terminal)"
                          ) -> None:
    """Add ``--no-progress`` (``args.no_progress``), and ``old`` as hidden aliases of it."""
    parser.add_argument("--no-progress", dest="no_progress", action="store_true", help=help)
    for name in old:
        parser.add_argument(name, dest="no_progress", action="store_true", help=argparse.SUPPRESS)
