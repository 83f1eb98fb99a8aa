"""Open a recording for replay by its suffix: .xtf, .jsf or (else) .atrlog. Kept apart from the
node so that a command checks its input before it loads the detectors, the fusion and their
scipy and OpenCV (a missing or navigation-only file fails in a fraction of a second)."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

from .atrlog import LogRecord


def open_recording(path: str | Path, *, crs: str = "", altitude: str = "auto",
                   frequency: str | float = "high") -> Iterable[LogRecord]:
    """Records of an .atrlog or an .xtf file, for replay; ``crs``: of XTF positions in
    projected metres (``--crs``, :mod:`atr_node.io.crs`). A file that needs it and has none
    fails here, before the first record. ``altitude``: of XTF tiles (``recording.altitude``);
    ``frequency``: the side-scan channels of a dual-frequency XTF (``recording.frequency``;
    JSF subsystems are chosen with ``convert --subsystem``)."""
    p = str(path)
    if p.lower().endswith(".xtf"):
        from .xtf import iter_xtf_records

        return iter(iter_xtf_records(p, crs=crs, altitude=altitude, frequency=frequency))
    if p.lower().endswith(".jsf"):  # EdgeTech JSF: same records, same options (:mod:`atr_node.io.jsf`)
        from .jsf import iter_jsf_records

        return iter(iter_jsf_records(p, crs=crs, altitude=altitude, frequency=frequency))
    from .atrlog import AtrLogReader

    return AtrLogReader(p)  # iterable, and keeps its counts (records rejected, garbage) for the summary
