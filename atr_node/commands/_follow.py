"""Options shared by the commands that follow a live node (export, monitor, exwpt): CURVE
keys for a node whose PUB socket is a CURVE server (``atr_node.security``) and the snapshot
endpoint for late joiners (ICD v1.1). Kept apart from
``atr_node.operators`` so that building the CLI's parsers imports no ZeroMQ."""

from __future__ import annotations

import argparse
import logging
import math
from typing import Any

from ..errors import AtrError

log = logging.getLogger(__name__)


def add_curve_arguments(parser: argparse.ArgumentParser) -> None:
    """``--curve-key`` / ``--node-key``: follow a node whose PUB socket uses CURVE."""
    parser.add_argument("--curve-key", metavar="FILE",
                        help="this tool's CURVE key pair (certificate with secret key, mode 0600), for a node "
                             "with links.curve_secret_key_file set; its public key must be authorized there")
    parser.add_argument("--node-key", metavar="FILE", help="the node's public key certificate (with --curve-key)")


def add_snapshot_argument(parser: argparse.ArgumentParser) -> None:
    """``--snapshot``: where to ask a late-joining node for its live contacts (ICD v1.1)."""
    parser.add_argument("--snapshot", metavar="ENDPOINT",
                        help="the node's snapshot endpoint, for the contacts published before this tool "
                             "started (ICD v1.1; default: the port after the PUB endpoint, or "
                             "links.snapshot_endpoint of --config; 'none' = do not ask)")
    parser.add_argument("--snapshot-timeout", metavar="S", type=_seconds, default=2.0,
                        help="how long to wait for the snapshot before following without it (default 2 s)")


def _seconds(text: str) -> float:
    """A finite number of seconds > 0, for argparse (a bad one is a usage error naming the option)."""
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds > 0, got {text!r}")
    return v


def snapshot_from_args(args: argparse.Namespace, settings: Any = None) -> str | None:
    """The snapshot endpoint to ask (None: do not ask): ``--snapshot``; else the port after
    ``--from``; else ``links.snapshot_endpoint`` of ``settings`` (the ``--config`` the PUB
    endpoint came from)."""
    if args.snapshot is not None:
        return None if args.snapshot in ("", "none") else args.snapshot
    if getattr(args, "endpoint", None):
        from ..node.snapshot_endpoint import derived_snapshot_endpoint

        derived = derived_snapshot_endpoint(args.endpoint)
        if derived is None and "://" in args.endpoint:  # ipc://: follow without (a bad --from fails on its own)
            log.warning("no snapshot endpoint for --from %s (the port after a tcp:// one is the default): give "
                        "--snapshot ENDPOINT for the contacts published before this tool started", args.endpoint)
        return derived
    return (settings.links.snapshot_endpoint or None) if settings is not None else None


def follow_endpoint(args: argparse.Namespace, settings: Any = None) -> str:
    """The PUB endpoint to follow (``--from``, else ``links.publish_endpoint`` of ``settings``),
    checked with the ``--snapshot`` one before any socket: a bad one fails in one line naming
    the option."""
    from ._endpoints import check_endpoint, check_optional_endpoint

    check_optional_endpoint(getattr(args, "snapshot", None), "--snapshot")
    if getattr(args, "endpoint", None):
        return check_endpoint(args.endpoint, "--from")
    return check_endpoint(settings.links.publish_endpoint, "links.publish_endpoint")


def curve_from_args(args: argparse.Namespace) -> Any:
    """The CURVE client settings of ``--curve-key``/``--node-key`` (None when neither is given)."""
    if not args.curve_key and not args.node_key:
        return None
    if not (args.curve_key and args.node_key):
        raise AtrError("--curve-key and --node-key go together: this tool's key pair and the node's public key")
    from ..security import CurveConfig, load_keypair, load_public_key

    return CurveConfig(keys=load_keypair(args.curve_key), server_public_key=load_public_key(args.node_key))
