"""The ``atr-node`` command (ICD section 6).

Each subcommand lives in ``atr_node/commands/<name>.py`` with two functions::

    def add_arguments(parser: argparse.ArgumentParser) -> None: ...
    def run(args: argparse.Namespace) -> int: ...          # the exit status

A subcommand whose module does not exist yet is listed, says that it is not built yet, and
exits with status 2: it never pretends to work.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import re
import sys
import traceback

from . import __version__
from .errors import AtrError, describe

EXIT_STATUS = """exit status:
  0    done
  1    bad input or a failure at run time: what was wrong and where, in one line on stderr
       (-v adds the traceback of an unexpected error); no partial output file is left
  2    usage: an unknown, missing or ill-formed option (argparse's message and the usage)
  130  interrupted (Ctrl-C)"""
"""The epilog of every subcommand's --help; a module may add lines of its own cases as
``EXIT_DETAIL``."""

# name -> (one-line help, issue that builds it)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("the main job on built-in data: simulate a multi-leg mission, calibrate, run the node, "
             "score against the truth, write the report and plots", "evaluation and demo"),
    "run": ("the on-vehicle daemon on live links (--config FILE)", "node"),
    "replay": ("feed a recording (.atrlog, .xtf or .jsf) through the node's pipeline", "node"),
    "simulate": ("generate a synthetic multi-leg mission: .atrlog and truth CSV", "simulation"),
    "calibrate": ("estimate detector confidence and P(y) curves by target injection", "calibration"),
    "evaluate": ("score contacts against a truth CSV and draw ROC curves", "evaluation and demo"),
    "bench": ("benchmarks of detectors, fusion, simulation and the node", "detectors"),
    "convert": ("convert between .xtf and .atrlog, or .jsf to .atrlog", "real recordings"),
    "batch": ("process many recordings on a Dask cluster and merge their evidence", "scale-out"),
    "monitor": ("live view of a node: heartbeat and contacts", "operators' tools"),
    "export": ("export contacts to GeoJSON, KML or CSV", "operators' tools"),
    "exwpt": ("send a live node's contacts over serial as SonarWiz $EXWPT sentences", "operators' tools"),
    "info": ("show the settings a config file gives, and what is built", "foundation"),
}


def _module_name(cmd: str) -> str:
    return f"atr_node.commands.{cmd}"


def _is_built(cmd: str) -> bool:
    return importlib.util.find_spec(_module_name(cmd)) is not None


def _not_built(args: argparse.Namespace) -> int:
    issue = COMMANDS[args.command][1]
    print(f"atr-node {args.command}: not built yet (it comes with the {issue} issue).", file=sys.stderr)
    return 2


def _plain(doc: str) -> str:
    """A module docstring as --help text: reST markers dropped (``Examples::`` -> ``Examples:``,
    double back-quotes -> none), since argparse prints the text as it is."""
    text = re.sub(r"::$", ":", doc.strip(), flags=re.M)
    return text.replace("``", "")


def _chosen(argv: list[str]) -> str | None:
    """The subcommand named on a command line, if any: the first word that is not an option
    (the top-level options, -v and --version, take no value)."""
    for word in argv:
        if word == "--":
            return None
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole parser; with ``only``, only that subcommand's module is imported (none for
    ``only=""``) and the others are listed by their one-line help: what ``atr-node CMD ...`` and
    ``atr-node --help`` need. A command's module may import numpy, scipy and OpenCV; the
    others' need not load to run it."""
    parser = argparse.ArgumentParser(
        prog="atr-node",
        description="Automatic target recognition for mine-hunting AUV synthetic aperture sonar: four detectors, "
                    "through-the-sensor performance estimates, Dempster-Shafer fusion across detectors and legs.",
    )
    parser.add_argument("--version", action="version", version=f"atr-node {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (help_text, issue) in COMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=help_text if _is_built(name) else f"{help_text} [not built yet]")
        elif _is_built(name):
            mod = importlib.import_module(_module_name(name))
            detail = getattr(mod, "EXIT_DETAIL", "")
            p = sub.add_parser(name, help=help_text, description=_plain(mod.__doc__ or help_text),
                               epilog=EXIT_STATUS + (f"\n{detail}" if detail else ""),
                               formatter_class=argparse.RawDescriptionHelpFormatter)
            mod.add_arguments(p)
            p.set_defaults(func=mod.run)
        else:
            p = sub.add_parser(name, help=f"{help_text} [not built yet]",
                               description=f"{help_text}.\n\nNot built yet: it comes with the {issue} issue.",
                               epilog="exit status: 2 (not built yet)")
            p.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
            p.set_defaults(func=_not_built)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(only=_chosen(sys.argv[1:] if argv is None else argv) or "")
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if not args.command:
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except AtrError as exc:
        return _fail(args, describe(exc))
    except KeyboardInterrupt:
        print(f"atr-node {args.command}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # a file or socket the command was given: name it, no traceback
        where = exc.filename if exc.filename is not None else ""
        why = exc.strerror or describe(exc)
        return _fail(args, f"{where}: {why}" if where else why)
    except Exception as exc:  # a bug or a case without its own message yet: still one line
        return _fail(args, f"unexpected {type(exc).__name__}{f': {exc}' if str(exc).strip() else ' (with no message)'}"
                           + ("" if args.verbose else " (run with -v for the traceback)"))


def _fail(args: argparse.Namespace, message: str) -> int:
    """Print the one-line error of a failed command (the traceback too with -v); exit status 1."""
    if args.verbose:
        traceback.print_exc(file=sys.stderr)
    first = " ".join(message.split())  # one line even when a message holds newlines
    print(f"atr-node {args.command}: error: {first}", file=sys.stderr)
    return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
