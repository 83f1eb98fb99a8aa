"""``--crs`` (ICD v1.1 section 6) and ``--frequency`` (the project's own), shared by the
commands that read XTF (replay, convert, batch, calibrate, evaluate): the command line's value
wins over the ``recording.crs`` and ``recording.frequency`` keys."""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from ..io.crs import EXAMPLE_CRS, projection


def add_crs_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--crs", metavar="CRS", default=None,
                        help="coordinate reference system of XTF positions in projected metres (NavUnits 0), "
                             f"e.g. {EXAMPLE_CRS} for UTM 10N (default: recording.crs; positions in degrees "
                             "need none)")


def resolve_crs(cli_value: str | None, settings: Any = None) -> str:
    """The CRS to read recordings with ("" = none): ``--crs`` if given, else ``recording.crs``;
    validated now, so an unknown one fails before any work (one line naming where it came from)."""
    if cli_value is None and settings is None:
        return ""
    crs, option = (cli_value, "--crs") if cli_value is not None else (settings.recording.crs, "recording.crs")
    if crs:
        projection(crs, option=option)
    return crs


def add_frequency_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frequency", metavar="high|low|KHZ", default=None,
                        help="XTF of a dual-frequency sonar: the side-scan channels to read, high (the finer "
                             "resolution), low, or a frequency in kHz (default: recording.frequency, high)")


def resolve_frequency(cli_value: str | None, settings: Any) -> Any:
    """``settings`` with ``recording.frequency`` from ``--frequency`` when given (checked now: a
    bad one fails in one line naming the option); the settings as they are otherwise."""
    if cli_value is None:
        return settings
    from ..config import frequency_choice

    return settings.replace(recording=dataclasses.replace(settings.recording,
                                                          frequency=frequency_choice(cli_value, "--frequency")))


def with_recording_options(args: argparse.Namespace, settings: Any) -> Any:
    """``settings`` with the command line's ``--frequency`` and ``--crs`` in ``recording`` (both
    checked now), for commands whose work reads them from the settings (batch tasks, evaluate)."""
    settings = resolve_frequency(getattr(args, "frequency", None), settings)
    crs = resolve_crs(getattr(args, "crs", None), settings)
    if crs != settings.recording.crs:
        settings = settings.replace(recording=dataclasses.replace(settings.recording, crs=crs))
    return settings
