"""Shared helpers of the reliability tests: the tools loaded as modules, a small mission."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path



TOOLS = Path(__file__).resolve().parents[2] / "tools"

def load_tool(name: str):
    """Import ``tools/<name>.py`` or ``tools/*/<name>.py`` as a module (the tools are scripts,
    not a package)."""
    if name in sys.modules:
        return sys.modules[name]
    path = TOOLS / f"{name}.py"
    if not path.is_file():  # the long-run tools live in tools/soak/
        path = next(TOOLS.glob(f"*/{name}.py"), path)
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod
