"""Checks of a command's input recording made before any work or output: a file that holds
no sonar tile (a navigation-only XTF, an .atrlog of NMEA alone) is bad input for a command
whose job is the tiles (replay, convert to XTF, evaluate --log, calibrate --input), not an
empty success."""

from __future__ import annotations

from pathlib import Path

from ..errors import AtrError


def require_sonar_tile(path: str | Path, *, crs: str = "", frequency: str | float = "high") -> None:
    """Raise :class:`AtrError` (``FILE: no sonar tile in N records``) unless the recording at
    ``path`` (.atrlog, .xtf or .jsf) holds a sonar tile. Reads up to the first tile only, so a
    normal recording costs one record or a few; an unreadable file fails with its reader's
    own one-line error (missing, empty, not a recording). XTF and JSF are read with their
    recorded altitude: tracking the first bottom return here would only repeat the work the
    command's own read does on the same first block."""
    p = Path(path)
    if p.is_dir():
        raise AtrError(f"{p}: a folder; expected a recording file (.atrlog, .xtf or .jsf)")
    if not p.exists():
        raise AtrError(f"{p}: cannot open: No such file or directory; expected a recording (.atrlog, .xtf or .jsf)")
    from ..io.recording import open_recording

    records = 0
    for rec in open_recording(p, crs=crs, altitude="altimeter", frequency=frequency):
        if rec.link == "sonar":
            return
        records += 1
    raise AtrError(f"{p}: no sonar tile in {records} records (navigation only?); expected a recording with "
                   f"side-scan or SAS tiles")
