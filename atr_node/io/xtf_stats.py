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
    quirks: Counter = field(default_factory=Counter)
    """The ``bad`` packets and other per-packet oddities by kind (``zero date (attitude)``,
    ``short packet (sonar)``, ...): counted, the first of each kind in ``quirk_examples``."""
    quirk_examples: dict[str, str] = field(default_factory=dict)
    """kind -> the message of its first packet (with its byte offset)."""
    positions: str = ""
    """What the file's positions are and how they were read (NavUnits, ``--crs``)."""
    pings: int = 0
    """Sonar pings turned into tile rows."""
    pings_dropped: Counter = field(default_factory=Counter)
    """Sonar pings not used, by reason (``bad_time``, ``time_backwards``, ``no_range``, ...)."""
    pings_without_nav: int = 0
    channels_used: Counter = field(default_factory=Counter)
    """Side-scan channels read (one per side and ping), by frequency in Hz (0: unknown)."""
    channels_unused: Counter = field(default_factory=Counter)
    """Side-scan channels of a side that had another one (dual-frequency sonars) and were not
    read, by frequency in Hz."""
    tiles: int = 0
    nav_fixes: int = 0
    nmea: Counter = field(default_factory=Counter)
    """Synthesised NMEA sentences by type."""
    altitude_from_sonar: int = 0
    """Pings whose tile altitude is the sonar's first return (``altitude="sonar"`` or ``auto``)."""
    altitude_source: Counter = field(default_factory=Counter)
    """Pings in tiles with nav by the source of their altitude: ``recorded``, ``image`` (the
    first bottom return, :mod:`.xtf_bottom`), ``nominal`` (neither: ``sensor.altitude_m``)."""
    altitude_recorded_bad: Counter = field(default_factory=Counter)
    """Pings whose recorded altitude is ``zero``, ``missing`` (negative, not finite) or, in
    ``auto``, ``inconsistent with the image``."""
    altitude_image_carried: int = 0
    """Pings whose image altitude was carried from neighbouring pings (no clear return)."""
    altitude_sides_resampled: int = 0
    """Pings whose port and starboard range axes differ (sample count, spacing, first range):
    tracked with the coarser side resampled onto the finer one's axis."""
    pings_resampled: int = 0
    """Pings whose range axis differed from their tile's below 1e-4 relative, resampled onto it."""
    nav_jumps: int = 0
    """Ping-to-ping steps faster than 15 m/s inside tiles (kept, flagged for the node)."""
    sensor_defaults: tuple[str, ...] = ()
    """Sensor map fields not in the file, taken from the settings."""
    truncated: bool = False
    errors: list[str] = field(default_factory=list)
    """File-level problems (truncation, positions), with where."""

    def quirk(self, kind: str, message: str) -> None:
        """Count one packet of a kind of quirk; keep the message of the first only (an older
        file can have thousands of packets with the same quirk: one line each is noise)."""
        self.quirks[kind] += 1
        self.quirk_examples.setdefault(kind, message)

    def altitude_line(self) -> str:
        """Which altitude the tiles carry, e.g. ``altitude: image first return for 1446 of
        1446 pings (recorded altitude 0 in 1446)``."""
        n = sum(self.altitude_source.values())
        if not n:
            return "altitude: no tile with nav"
        img, nom = self.altitude_source["image"], self.altitude_source["nominal"]
        rec = n - img - nom
        bad = ", ".join(f"{'0' if k == 'zero' else k} in {v}" for k, v in sorted(self.altitude_recorded_bad.items()) if v)
        if img:
            text = f"altitude: image first return for {img} of {n} pings" + (f", recorded for {rec}" if rec else "")
        else:
            text = f"altitude: recorded for {rec} of {n} pings" if nom else f"altitude: recorded for {n} pings"
        if nom:
            text += f", nominal (sensor.altitude_m) for {nom}"
        if bad:
            text += f" (recorded altitude {bad})"
        if self.altitude_sides_resampled:
            text += (f"; {self.altitude_sides_resampled} pings with port and starboard on different range axes "
                     "(tracked on one)")
        if self.altitude_image_carried:
            text += f"; {self.altitude_image_carried} pings without a clear return carried from their neighbours"
        return text

    def frequency_line(self) -> str:
        """Which side-scan channels were read where a side had more than one (empty when none
        had), e.g. ``side-scan: 500 kHz (2000) read, 100 kHz (2000) not (channel-pings);
        --frequency high, low or kHz chooses``."""
        if not self.channels_unused:
            return ""
        def text(c: Counter) -> str:
            return ", ".join(f"{hz / 1e3:g} kHz ({n})" if hz > 0 else f"unknown frequency ({n})"
                             for hz, n in sorted(c.items()))

        used, unused = text(self.channels_used), text(self.channels_unused)
        return (f"side-scan: {used or 'nothing'} read, {unused} not (channel-pings); "
                "--frequency high, low or kHz chooses")

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
        if self.channels_unused:
            lines.append(f"  {self.frequency_line()}")
        if self.altitude_source:
            lines.append(f"  {self.altitude_line()}")
        if self.pings_resampled:
            lines.append(f"  pings resampled onto their tile's range axis (spacing drift < 1e-4): "
                         f"{self.pings_resampled}")
        if self.positions:
            lines.append(f"  positions: {self.positions}")
        if self.quirks:
            lines.append(f"  {sum(self.quirks.values())} packets with quirks (not used): "
                         + ", ".join(f"{k} x {v}" for k, v in sorted(self.quirks.items())))
            lines.extend(f"    first {k}: {self.quirk_examples[k]}" for k in sorted(self.quirks))
        if self.nav_jumps:
            lines.append(f"  nav jumps {self.nav_jumps}")
        if self.sensor_defaults:
            lines.append(f"  sensor fields not in the file (from settings): {', '.join(self.sensor_defaults)}")
        lines.extend(f"  {e}" for e in self.errors)
        return "\n".join(lines)
