"""Feed a recording through the node's pipeline, exactly as aboard (ICD section 6).

The recording is an .atrlog (ICD section 4), an .xtf or an EdgeTech .jsf side-scan file (the
JSF's first side-scan subsystem; convert it with --subsystem to pick another). Records are paced at
their recorded times times --speed (or as fast as possible with --speed max); the pipeline
is the on-vehicle one in replay mode: it never degrades or drops for load, so the same log and
options always give the same contacts. Tiles with no usable navigation are dropped and
counted by reason in the end-of-run line, the heartbeat's tiles_dropped and --summary. XTF
positions in projected metres (NavUnits 0) need --crs (e.g. --crs EPSG:32610): without it
such a file fails at once. Contacts and heartbeats are published on ZeroMQ as
in ICD section 3, with the snapshot endpoint for late joiners (ICD v1.1; --snapshot, by default
the port after --publish); --contacts-out writes the final state of every contact as JSON lines.

With --state-dir, the node snapshots there as it goes; run the same command again after a
crash (even SIGKILL) and it resumes from the last snapshot and ends with the same contacts.

An .atrlog's damaged records (or garbage bytes) cost only themselves: they are counted by
reason at the end of the end-of-run line and in --summary's "recording".
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import sys
import threading
import time

from ..config import load_settings
from ..errors import AtrError
from ..io.atomic import atomic_open
from ._crs import add_crs_argument, add_frequency_argument, resolve_crs, resolve_frequency
from ._endpoints import check_optional_endpoint
from ._inputs import require_sonar_tile
from ._progress import add_progress_argument

log = logging.getLogger(__name__)

EXIT_DETAIL = """replay: 0 at the end of the recording; 1 also for a file that is not a recording or holds no
sonar tile, and for a bad --publish/--snapshot endpoint or one in use; 130 after a snapshot with --state-dir"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG", help="recording: .atrlog, .xtf or .jsf")
    parser.add_argument("--config", metavar="FILE", help="TOML settings (default: built-in defaults)")
    parser.add_argument("--model", metavar="FILE", help="performance model (default: the one shipped)")
    parser.add_argument("--online-calibration", choices=("on", "off"), default="on",
                        help="calibrate on-line from the first tiles, as aboard (default: on)")
    parser.add_argument("--speed", default="max", metavar="FACTOR|max",
                        help="replay speed: a factor of the recorded pace (1 = real time) or max (default: max)")
    parser.add_argument("--publish", metavar="ENDPOINT",
                        help="ZeroMQ PUB endpoint (default: links.publish_endpoint; 'none' = do not publish)")
    parser.add_argument("--snapshot", metavar="ENDPOINT",
                        help="snapshot endpoint for late joiners, ICD v1.1 (default: the port after --publish "
                             "when given, else links.snapshot_endpoint; 'none' = off)")
    parser.add_argument("--contacts-out", metavar="FILE", help="write the final contacts as JSON lines")
    parser.add_argument("--detections-out", metavar="FILE",
                        help="write every detection fused (detector, leg, position, gamma, confidence) as JSON lines")
    parser.add_argument("--state-dir", metavar="DIR", help="snapshot here and resume from here after a crash")
    parser.add_argument("--workers", type=int, default=1, choices=(0, 1),
                        help="1: detection in a worker process (both cores); 0: one process")
    parser.add_argument("--summary", metavar="FILE", help="write run counters and timings as JSON")
    add_progress_argument(parser)
    add_crs_argument(parser)
    add_frequency_argument(parser)


def _speed(text: str) -> float | None:
    if text == "max":
        return None
    try:
        v = float(text)
    except ValueError:
        raise AtrError(f"--speed {text!r}: expected a factor > 0 or 'max'") from None
    if not 0 < v < float("inf"):
        raise AtrError(f"--speed {text!r}: expected a factor > 0 or 'max'")
    return v


def build_model(settings, model_path: str | None, online: str, *, deterministic: bool):
    """The performance model to start with, and the on-line calibrator (or None)."""
    from ..calibration.model import PerformanceModel

    model = PerformanceModel.load(model_path) if model_path else PerformanceModel.shipped()
    calibrator = None
    if online == "on":
        from ..calibration.online import OnlineCalibrator

        calibrator = OnlineCalibrator(settings, model, deterministic=deterministic)
    return model, calibrator


def run(args: argparse.Namespace) -> int:
    settings = resolve_frequency(getattr(args, "frequency", None), load_settings(args.config))
    speed = _speed(args.speed)
    publish_where = "--publish" if args.publish is not None else "links.publish_endpoint"
    publish = check_optional_endpoint(args.publish if args.publish is not None else settings.links.publish_endpoint,
                                      publish_where)
    check_optional_endpoint(getattr(args, "snapshot", None), "--snapshot")
    if getattr(args, "snapshot", None) is None and args.publish is None:
        check_optional_endpoint(settings.links.snapshot_endpoint, "links.snapshot_endpoint")
    # checked first: a recording that cannot be read, holds no tile or needs --crs fails before the node starts
    crs = resolve_crs(getattr(args, "crs", None), settings)
    require_sonar_tile(args.log, crs=crs, frequency=settings.recording.frequency)
    # the node (detectors, fusion, their scipy and OpenCV) loads once the input is known good
    from hw.replay import IterLink, Paced

    from ..io.recording import open_recording
    from ..node.service import NodeService, write_contacts, write_detections
    from ..node.snapshot_endpoint import node_snapshot_endpoint

    recording = open_recording(args.log, crs=crs, altitude=settings.recording.altitude,
                               frequency=settings.recording.frequency)
    model, online = build_model(settings, args.model, args.online_calibration, deterministic=True)
    publish = None if publish in ("", "none") else publish
    snapshot, snapshot_setting = node_snapshot_endpoint(settings, publish_arg=args.publish,
                                                        snapshot_arg=getattr(args, "snapshot", None))
    from ..node.state import recording_identity

    # a --state-dir of another recording is set aside, not resumed (its evidence is not this one's)
    source_id = recording_identity(args.log) if args.state_dir else None
    service = NodeService(settings, model=model, mode="replay", workers=args.workers, online=online,
                          publish=publish, state_dir=args.state_dir, source_name=str(args.log),
                          snapshot=snapshot, snapshot_setting=snapshot_setting, source_id=source_id)
    service.install_signal_handlers()
    t0 = time.monotonic()
    progress = None
    try:
        skip = service.resume()
        records = itertools.islice(recording, skip, None)
        source = IterLink(records, name=str(args.log))
        link = Paced(source, speed) if speed is not None else source
        progress = _Progress(service, quiet=args.no_progress or not sys.stderr.isatty())
        ended = service.run(link, start=skip)
        progress.done()
        wall = time.monotonic() - t0
        contacts = service.pipeline.contacts
        if args.contacts_out:
            write_contacts(args.contacts_out, contacts)
        if args.detections_out:
            write_detections(args.detections_out, service.pipeline)
        summary = service.summary()
        summary["wall_s"] = round(wall, 3)
        summary["mpx_per_s"] = round(summary["pixels"] / 1e6 / max(wall, 1e-9), 2)
        read_text = _recording_counts(recording, summary)
        if args.summary:
            with atomic_open(args.summary, "w") as fh:
                json.dump(summary, fh, indent=2, default=str)
        live = sum(1 for c in contacts if c["state"] != "withdrawn")
        print(f"atr-node replay: {summary['tiles_in']} tiles in, {summary['tiles_done']} done, "
              f"{summary['tiles_rejected']} rejected, {dropped_text(summary)}; {live} contacts ({len(contacts)} ever); "
              f"{summary['mpx_per_s']} Mpx/s over {wall:.1f} s; {summary['model']['short']}{read_text}"
              f"{notes_text(summary)}",
              file=sys.stderr)
        return 0 if ended else 130
    finally:
        if progress is not None:
            progress.done()
        service.close()


def _recording_counts(recording, summary: dict) -> str:
    """Put the .atrlog reader's counts (records rejected or skipped as garbage, by reason) in
    ``summary["recording"]`` and ``summary["rejections"]`` (as ``recording: <reason>``); return
    them for the end-of-run line (``; 2 records rejected: ...``), or ``""`` when none."""
    report = getattr(recording, "report", None)
    if report is None:  # .xtf, .jsf: their readers count their own way
        return ""
    summary["recording"] = report()
    summary.setdefault("rejections", {}).update(
        {f"recording: {k}": v for k, v in summary["recording"]["reasons"].items()})
    text = recording.summary_text()
    return f"; {text}" if text else ""


def dropped_text(summary: dict) -> str:
    """``4 dropped (no usable nav x 4)``: the tiles dropped and why, for end-of-run lines."""
    reasons = summary.get("drop_reasons") or {}
    detail = ", ".join(f"{k} x {v}" for k, v in sorted(reasons.items()))
    return f"{summary['tiles_dropped']} dropped" + (f" ({detail})" if detail else "")


def notes_text(summary: dict) -> str:
    """``; nav rejected: nmea out_of_range x 3; 12 masses clamped to 1 - eps``: what the run
    counted and the rest of the end-of-run line does not say (``""`` when nothing)."""
    parts = []
    # the recording's own rejections are in the line already (_recording_counts)
    rejections = {k: v for k, v in (summary.get("rejections") or {}).items() if not k.startswith("recording: ")}
    if rejections:
        parts.append("rejected: " + ", ".join(f"{k} x {v}" for k, v in sorted(rejections.items())))
    nav = summary.get("nav") or {}
    rejected = [f"{link} {reason} x {n}" for link in ("nmea", "can")
                for reason, n in sorted((nav.get(link) or {}).items()) if reason != "accepted" and n]
    if rejected:
        parts.append("nav rejected: " + ", ".join(rejected))
    if summary.get("clamped"):
        parts.append(f"{summary['clamped']} masses clamped to 1 - eps")
    if summary.get("seq_repeats"):
        parts.append(f"{summary['seq_repeats']} tiles repeat a seq")
    if summary.get("strip_breaks"):
        parts.append("strips restarted: " + ", ".join(f"{k} x {v}" for k, v in sorted(summary["strip_breaks"].items())))
    if summary.get("navigation"):
        parts.append(summary["navigation"])
    return "".join(f"; {p}" for p in parts)


class _Progress:
    """A one-line progress report on stderr (records, tiles, contacts, rate), refreshed twice a
    second by a thread, so it keeps moving while the node waits for the on-line calibration
    (``calibrating on 8 tile(s): 34/80 injection rounds, waiting for the on-line model 3 s``)
    instead of looking hung."""

    def __init__(self, service, *, quiet: bool) -> None:
        self.service, self.quiet = service, quiet
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread = None
        if not quiet:
            self._thread = threading.Thread(target=self._loop, name="atr-progress", daemon=True)
            self._thread.start()

    def line(self) -> str:
        now = time.monotonic()
        st = self.service.pipeline.stats
        online = self.service.pipeline.online
        since = getattr(online, "waiting_since", None) if online is not None else None
        if since is not None:
            done, total = online.progress
            stage = f"{done}/{total} injection rounds" if total else "gathering tiles"
            return (f"calibrating on {online.offered} tile(s): {stage}, waiting for the on-line model "
                    f"{now - since:.0f} s ({st.tiles_in} tiles in)")
        mpx = st.pixels / 1e6 / max(now - self._t0, 1e-9)
        tracker = self.service.pipeline.tracker  # one atomic read of a dict's size: no copy, no race
        live = len(tracker.live) if tracker is not None else 0
        return f"{st.records} records, {st.tiles_in} tiles, {live} contacts, {mpx:.1f} Mpx/s"

    def _loop(self) -> None:
        while not self._stop.wait(0.5):
            try:
                text = self.line()
            except Exception:  # a read racing the node's own update: skip this refresh
                continue
            sys.stderr.write(f"\r  {text:<90}")
            sys.stderr.flush()

    def done(self) -> None:
        """Stop the refresh and end the line (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            sys.stderr.write("\n")
