"""Output files that appear whole or not at all.

A command that fails half way must leave no partial output behind (a 0-byte ``.atrlog``, a
contacts file cut mid-line): each file is written under a temporary name in its own folder
(so the final rename stays on one file system and is atomic) and renamed over the target
only when complete; on any error the temporary file is removed and the target is untouched.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import IO, Iterator


def temporary_name(path: str | os.PathLike[str]) -> Path:
    """The hidden temporary name :func:`atomic_path` writes ``path`` under."""
    p = Path(path)
    return p.with_name(f".{p.name}.tmp-{os.getpid()}")


def leftover_temporaries(path: str | os.PathLike[str]) -> list[Path]:
    """Temporary files of ``path`` that writers killed mid-write left behind (any process)."""
    p = Path(path)
    return sorted(p.parent.glob(f".{p.name}.tmp-*"))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s content to; rename it over ``path`` when the
    block ends normally, remove it when the block raises (``KeyboardInterrupt`` included)."""
    target = Path(path)
    tmp = temporary_name(target)
    try:
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w", **kwargs) -> Iterator[IO]:
    """``open(path, mode)`` whose file appears at ``path`` only once closed without error."""
    if not mode.startswith("w"):
        raise ValueError(f"atomic_open writes whole files: mode 'w' or 'wb', got {mode!r}")
    with atomic_path(path) as tmp:
        with open(tmp, mode, **kwargs) as fh:
            yield fh
