"""Subcommands of ``atr-node``: one module each, with ``add_arguments(parser)`` and ``run(args)``."""
