"""The exception tree of atr-node.

Every error raised on purpose by the package derives from :class:`AtrError`, and its message
says what was wrong, where (file, key, tile, byte offset) and what was expected::

    AtrError
     +-- ConfigError           a configuration file or key (names the file and the key)
     +-- TileError             a sonar tile breaking ICD section 1 (names the tile and field)
     +-- NavError              navigation unusable: missing, stale, out of span
     +-- LogFormatError        an .atrlog record (names the file and the byte offset)
     +-- ModelFileError        a detector performance-model file (version, corruption)
     +-- GeometryError         impossible geometry (altitude, ranges, frames)
     +-- FusionError           evidence, masses or an evidence-grid snapshot (names which)
     +-- NotBuiltError         a command or feature that is not built yet

Link drivers (package ``hw``) derive their errors from ``hw.errors.LinkError``, itself an
:class:`AtrError`.
"""

from __future__ import annotations


class AtrError(Exception):
    """Base of every error atr-node raises on purpose."""


class ConfigError(AtrError, ValueError):
    """A configuration file, section or key is unknown, ill-typed or out of range."""

    def __init__(self, message: str, *, path: str | None = None, key: str | None = None):
        self.path = path
        self.key = key
        where = ", ".join(p for p in (f"file {path}" if path else "", f"key '{key}'" if key else "") if p)
        super().__init__(f"{where}: {message}" if where else message)


class TileError(AtrError, ValueError):
    """A sonar tile map breaks ICD section 1."""

    def __init__(self, message: str, *, tile: str = "tile ?", field: str | None = None):
        self.tile = tile
        self.field = field
        where = f"{tile}" + (f", field '{field}'" if field else "")
        super().__init__(f"{where}: {message}")


class NavError(AtrError, ValueError):
    """Navigation is missing, stale or does not span the requested times."""


class LogFormatError(AtrError, ValueError):
    """An .atrlog record is malformed."""

    def __init__(self, message: str, *, path: str | None = None, offset: int | None = None):
        self.path = path
        self.offset = offset
        where = f"{path or '<stream>'}" + (f" at byte {offset}" if offset is not None else "")
        super().__init__(f"{where}: {message}")


class ModelFileError(AtrError, ValueError):
    """A detector performance-model file is corrupted or of an unsupported version."""


class GeometryError(AtrError, ValueError):
    """Impossible sensor or target geometry."""


class FusionError(AtrError, ValueError):
    """Evidence that breaks SPEC sections 6-7 (masses outside [0, 1], total conflict, a closed
    leg observed again, shapes that disagree) or an unreadable evidence-grid snapshot."""


class NotBuiltError(AtrError):
    """A command or feature that is not built yet."""


def describe(exc: BaseException) -> str:
    """What an exception says, never an empty string: its message, or its type when it has
    none (``str(OSError())`` and ``str(KeyError())`` are ``""``, and a warning or an error
    line must still say what went wrong)."""
    text = str(exc)
    return text if text.strip() else f"{type(exc).__name__} (with no message)"
