"""Convert a recording between XTF and .atrlog, or an EdgeTech JSF file to .atrlog.

  atr-node convert survey.xtf survey.atrlog     XTF side-scan -> tiles (slant range, as
                                                recorded) and NMEA navigation records
  atr-node convert mission.atrlog mission.xtf   sonar tiles -> XTF ping packets (port and
                                                starboard of the same pings together)
  atr-node convert survey.jsf survey.atrlog     EdgeTech JSF side-scan (message 80 pings of
                                                one subsystem: --subsystem) -> tiles and NMEA

The direction follows the suffixes. What was read, skipped (unknown XTF packet types, records
XTF cannot hold) and dropped is printed at the end, packets with the same quirk (a zero date,
too short) as one count per kind; the exit status is 0 when the conversion ran to the end of
the input, even if some packets or records were skipped. OUT is written under a temporary name
in its folder and renamed when complete: after an error there is no OUT (nor a partial one).

--crs: XTF -> atrlog, the CRS of positions in projected metres (NavUnits 0; such a file fails
at once without it); atrlog -> XTF, write positions as easting and northing in that CRS.

--frequency: XTF of a dual-frequency sonar (two side-scan channels per side), which to read:
high (default), low or a frequency in kHz; the channels not read are counted in the summary."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import AtrError
from ..io.atrlog import AtrLogReader, AtrLogWriter
from ..io.xtf import DEFAULT_TILE_PINGS, XtfReader
from ..io.xtf_write import XtfWriter
from ..io.atomic import atomic_path
from ..config import frequency_choice
from ._crs import add_crs_argument, add_frequency_argument, resolve_crs
from ._inputs import require_sonar_tile

EXIT_DETAIL = "convert: 1 also for an input that is not a recording or holds no sonar tile (OUT is then not written)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", metavar="IN", help="recording to read (.xtf, .jsf or .atrlog)")
    parser.add_argument("output", metavar="OUT", help="file to write (.atrlog or .xtf); overwritten")
    parser.add_argument("--tile-pings", type=int, default=DEFAULT_TILE_PINGS, metavar="N",
                        help=f"XTF -> atrlog: most pings per tile (default {DEFAULT_TILE_PINGS})")
    parser.add_argument("--mission", metavar="NAME", help="XTF -> atrlog: mission name (default: the file's)")
    parser.add_argument("--altitude", choices=("auto", "altimeter", "sonar"), default="auto",
                        help="XTF -> atrlog: tile altitude: auto (default) = the recorded one where plausible, "
                             "the image's first bottom return where it is zero, missing or inconsistent; "
                             "altimeter = as recorded; sonar = the image's first bottom return")
    parser.add_argument("--leg", type=int, metavar="N", help="XTF -> atrlog: leg number (default: the file's, or 0)")
    parser.add_argument("--subsystem", type=int, choices=(20, 21, 22), metavar="N",
                        help="JSF -> atrlog: side-scan subsystem to read, 20 low, 21 high, 22 very high "
                             "frequency (default: the first in the file; the others are counted as skipped)")
    add_crs_argument(parser)
    add_frequency_argument(parser)


def _kind(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in (".xtf", ".atrlog", ".jsf"):
        return suffix[1:]
    raise AtrError(f"{path}: unknown recording type {suffix or '(no suffix)'!r}; expected .xtf, .jsf or .atrlog")


def xtf_to_atrlog(src: Path, dst: Path, *, tile_pings: int, mission: str | None, leg: int | None,
                  altitude: str = "auto", crs: str = "", subsystem: int | None = None,
                  frequency: str | float = "high") -> str:
    """Write the records of an XTF (or, by suffix, JSF) file to an .atrlog; return the summary."""
    if src.suffix.lower() == ".jsf":
        from ..io.jsf import JsfReader

        reader = JsfReader(src, tile_pings=tile_pings, mission=mission, leg=leg, altitude=altitude, crs=crs,
                           subsystem=subsystem, frequency=frequency)
    else:
        reader = XtfReader(src, tile_pings=tile_pings, mission=mission, leg=leg, altitude=altitude, crs=crs,
                           frequency=frequency)
    with AtrLogWriter(dst, flush_every=256) as w:
        for rec in reader:
            w.write_record(rec)
    return f"{reader.stats.summary()}\nwrote {w.records} records to {dst}"


def atrlog_to_xtf(src: Path, dst: Path, *, crs: str = "") -> str:
    """Write the sonar tiles of an .atrlog to an XTF file (positions in ``crs`` when given);
    return the summary."""
    reader = AtrLogReader(src)
    with XtfWriter(dst, crs=crs) as w:
        for rec in reader:
            w.write_record(rec)
    s = w.stats
    lines = [f"{src}: {reader.records} records read, "
             + (reader.summary_text() if reader.rejected else "0 rejected")
             + (" (truncated last record)" if reader.truncated else ""),
             f"wrote {s.pings} pings from {s.tiles} tiles to {dst}"
             + (f" ({s.unpaired_tiles} tiles without their other side)" if s.unpaired_tiles else "")]
    if s.skipped:
        lines.append("  not in XTF: " + ", ".join(f"{k} records {v}" for k, v in sorted(s.skipped.items())))
    if s.rejected:  # counted, never listed one by one: the first says what was wrong
        lines.append(f"  {len(s.rejected)} tile record(s) not written (not a valid tile), e.g. {s.rejected[0]}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    src, dst = Path(args.input), Path(args.output)
    kin, kout = _kind(src), _kind(dst)
    if kin == kout:
        raise AtrError(f"{src} -> {dst}: both are .{kin}; convert goes from .xtf to .atrlog or back")
    if "jsf" in (kin, kout) and (kin, kout) != ("jsf", "atrlog"):
        raise AtrError(f"{src} -> {dst}: JSF is read only, into an .atrlog (convert survey.jsf survey.atrlog)")
    if not src.is_file():
        raise AtrError(f"{src}: no such file")
    if src.resolve() == dst.resolve():
        raise AtrError(f"{dst}: output would overwrite the input")
    if args.tile_pings < 1:
        raise AtrError(f"--tile-pings must be >= 1, got {args.tile_pings}")
    crs = resolve_crs(getattr(args, "crs", None))
    frequency = "high" if args.frequency is None else frequency_choice(args.frequency, "--frequency")
    if not dst.parent.is_dir():
        raise AtrError(f"{dst}: No such file or directory: no folder {dst.parent}")
    require_sonar_tile(src, crs=crs, frequency=frequency)
    try:
        with atomic_path(dst) as tmp:
            if kin in ("xtf", "jsf"):
                text = xtf_to_atrlog(src, tmp, tile_pings=args.tile_pings, mission=args.mission, leg=args.leg,
                                     altitude=args.altitude, crs=crs, subsystem=getattr(args, "subsystem", None),
                                     frequency=frequency)
            else:
                text = atrlog_to_xtf(src, tmp, crs=crs)
    except OSError as exc:
        raise AtrError(f"{exc.filename or dst}: {exc.strerror or exc}") from None
    text = text.replace(str(tmp), str(dst))  # the summary names the file the user asked for
    print(text, file=sys.stdout)
    return 0
