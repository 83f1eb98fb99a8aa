"""What reading one XTF file met: packets by type, what was skipped, dropped, synthesised."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field


@dataclass
class XtfStats:
    """What reading one XTF file met: counters only, filled while the file streams."""

    path: str = ""
    packets: Counter = field(default_factory=Counter)
    """Every packet read, by type name."""
    skipped: Counter = field(default_factory=Counter)
    """Packets read and not used (types not in the table, sub-bottom channels), by type name."""
    bad: int = 0
    """Packets whose content could not be parsed (skipped; framing intact)."""
    pings: int = 0
    """Sonar pings turned into tile rows."""
    pings_dropped: Counter = field(default_factory=Counter)
    """Sonar pings not used, by reason (``bad_time``, ``time_backwards``, ``no_range``, ...)."""
    pings_without_nav: int = 0
    tiles: int = 0
    nav_fixes: int = 0
    nmea: Counter = field(default_factory=Counter)
    """Synthesised NMEA sentences by type."""
    altitude_from_sonar: int = 0
    """Pings whose tile altitude is the sonar's first return (``altitude="sonar"``)."""
    nav_jumps: int = 0
    """Ping-to-ping steps faster than 15 m/s inside tiles (kept, flagged for the node)."""
    sensor_defaults: tuple[str, ...] = ()
    """Sensor map fields not in the file, taken from the settings."""
    truncated: bool = False
    errors: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """A few lines for the user: what was read, skipped and why."""
        lines = [f"{self.path}: {sum(self.packets.values())} packets "
                 f"({', '.join(f'{k} {v}' for k, v in sorted(self.packets.items())) or 'none'})",
                 f"  pings {self.pings}, tiles {self.tiles}, nav fixes {self.nav_fixes}, "
                 f"NMEA sentences {sum(self.nmea.values())} "
                 f"({', '.join(f'{k} {v}' for k, v in sorted(self.nmea.items())) or 'none'})"]
        if self.skipped:
            lines.append("  skipped: " + ", ".join(f"{k} {v}" for k, v in sorted(self.skipped.items())))
        if self.pings_dropped or self.pings_without_nav:
            lines.append(f"  pings dropped: {dict(self.pings_dropped) or 0}; pings without nav "
                         f"(tiles without nav map): {self.pings_without_nav}")
        if self.altitude_from_sonar:
            lines.append(f"  altitude from the sonar's first return on {self.altitude_from_sonar} pings")
        if self.bad or self.nav_jumps:
            lines.append(f"  unparsable packets {self.bad}, nav jumps {self.nav_jumps}")
        if self.sensor_defaults:
            lines.append(f"  sensor fields not in the file (from settings): {', '.join(self.sensor_defaults)}")
        lines.extend(f"  {e}" for e in self.errors)
        return "\n".join(lines)
