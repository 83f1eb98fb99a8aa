"""Options shared by the commands that follow a live node (export, monitor, exwpt): CURVE
keys for a node whose PUB socket is a CURVE server (``atr_node.security``). Kept apart from
``atr_node.operators`` so that building the CLI's parsers imports no ZeroMQ."""

from __future__ import annotations

import argparse
from typing import Any

from ..errors import AtrError


def add_curve_arguments(parser: argparse.ArgumentParser) -> None:
    """``--curve-key`` / ``--node-key``: follow a node whose PUB socket uses CURVE."""
    parser.add_argument("--curve-key", metavar="FILE",
                        help="this tool's CURVE key pair (certificate with secret key, mode 0600), for a node "
                             "with links.curve_secret_key_file set; its public key must be authorized there")
    parser.add_argument("--node-key", metavar="FILE", help="the node's public key certificate (with --curve-key)")


def curve_from_args(args: argparse.Namespace) -> Any:
    """The CURVE client settings of ``--curve-key``/``--node-key`` (None when neither is given)."""
    if not args.curve_key and not args.node_key:
        return None
    if not (args.curve_key and args.node_key):
        raise AtrError("--curve-key and --node-key go together: this tool's key pair and the node's public key")
    from ..security import CurveConfig, load_keypair, load_public_key

    return CurveConfig(keys=load_keypair(args.curve_key), server_public_key=load_public_key(args.node_key))
