"""Show the settings a configuration file gives (every key, with its value) and which
subcommands are built. A quick check that a config file is valid: an unknown or ill-typed
key is reported with the file and the key, and the exit status is 1."""

from __future__ import annotations

import argparse
import dataclasses

from ..config import load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", help="TOML settings (default: built-in defaults)")


def _walk(obj, prefix=""):
    for f in dataclasses.fields(obj):
        if f.name == "source":
            continue
        v = getattr(obj, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(v):
            yield from _walk(v, key + ".")
        else:
            yield key, v


def run(args: argparse.Namespace) -> int:
    from ..cli import COMMANDS, _is_built

    settings = load_settings(args.config)
    print(f"settings from {settings.source or 'built-in defaults'}:")
    for key, value in _walk(settings):
        print(f"  {key} = {value!r}")
    print("subcommands:")
    for name in COMMANDS:
        print(f"  {name:10s} {'built' if _is_built(name) else 'not built yet'}")
    return 0
