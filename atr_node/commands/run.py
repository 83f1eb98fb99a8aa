"""The on-vehicle daemon: live links through the pipeline, contacts on ZeroMQ (ICD section 6).

Opens the links of [links] (sonar tiles over ZeroMQ, NMEA INS over serial, CAN), records
everything received to an .atrlog in node.data_dir/recordings (the recording is also the
node's write-ahead log), runs the pipeline in live mode (degrades rather than queueing without
bound), publishes contacts and heartbeats, and snapshots to node.data_dir/state.

On start it resumes from the last snapshot: the records of its previous recording after the
snapshot's position are replayed first, so no accepted tile's evidence is lost across a
crash or a restart. SIGTERM (or SIGINT, Ctrl-C) drains, snapshots and exits 0. Under systemd
(Type=notify) it reports READY and feeds the watchdog.

It logs at INFO by default (``-vv`` for debug): the endpoints and socket types, which links
are configured, the model in use, "waiting for the first tile", the first tile in, and a
one-line summary at exit (tiles in/done/rejected/dropped, contacts, uptime).
"""

from __future__ import annotations

import argparse
import itertools
import logging
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from ..config import load_settings
from ._endpoints import check_link_endpoints

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", required=True, help="TOML settings")
    parser.add_argument("--model", metavar="FILE", help="performance model (default: the one shipped)")
    parser.add_argument("--online-calibration", choices=("on", "off"),
                        help="calibrate on-line from the first tiles (default: calibration.online)")
    parser.add_argument("--no-record", action="store_true", help="do not record the links (no resume after a crash)")


def run(args: argparse.Namespace) -> int:
    from hw import open_links
    from hw.recorder import LinkMux, RecordingLink

    from ..io.atrlog import AtrLogWriter, read_atrlog
    from ..node import state as node_state
    from ..node.service import NodeService
    from .replay import build_model

    for name in ("atr_node", "hw"):  # a daemon says what it does: INFO unless -v asked for more
        if logging.getLogger(name).getEffectiveLevel() > logging.INFO:
            logging.getLogger(name).setLevel(logging.INFO)
    settings = load_settings(args.config)
    check_link_endpoints(settings)  # a bad endpoint fails in one line naming the key, before any socket
    data = Path(settings.node.data_dir)
    state_dir = data / "state"
    rec_dir = data / "recordings"
    rec_dir.mkdir(parents=True, exist_ok=True)
    online = args.online_calibration or ("on" if settings.calibration.online else "off")
    model, calibrator = build_model(settings, args.model, online, deterministic=False)
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    recording = rec_dir / f"atr-{stamp}.atrlog"
    service = NodeService(settings, model=model, mode="live", workers=1, online=calibrator,
                          publish=settings.links.publish_endpoint, state_dir=state_dir, source_name=str(recording),
                          snapshot=settings.links.snapshot_endpoint or None)
    service.install_signal_handlers()
    try:
        # catch up: the previous recording past the snapshot (its source), without re-recording
        # the newest snapshot that reads back (a damaged one: the previous, or afresh; state.restore)
        meta = node_state.restore(state_dir, service.pipeline)
        if meta is not None:
            meta_folder = node_state.read_current(state_dir)
            service.sync_contact_view()  # late joiners get the restored contacts, then the replayed ones
            prev = Path(meta.get("source", ""))
            if prev.is_file():
                n = 0
                for rec in itertools.islice(read_atrlog(prev, allow_empty=True), int(meta["position"]), None):
                    service.pipeline.feed(rec)
                    n += 1
                log.warning("resumed from snapshot %s and replayed %d records of %s", meta_folder, n, prev)
            service.snapshot()  # now the state accounts for nothing of the new recording
        links = open_links(settings.links, curve=service.curve)
        if not links:
            print("atr-node run: no links configured in [links]", file=sys.stderr)
            return 1
        link = LinkMux(list(links.values()))
        if not args.no_record:
            link = RecordingLink(link, AtrLogWriter(recording, flush_every=1))
        for line in startup_lines(settings, links, service, model_path=args.model, calibrator=calibrator,
                                  recording=None if args.no_record else recording):
            log.info("%s", line)
        t0 = time.monotonic()
        service.run_live(link)
        link.shutdown()
        summary = service.summary()
        log.debug("summary: %s", summary)
        log.info("%s", exit_line(summary, live_contacts=len(service.pipeline.live_contacts()),
                                 uptime_s=time.monotonic() - t0))
        return 0
    finally:
        service.close()


def _zmq_link_text(link) -> str:
    """``ZeroMQ PULL connected to tcp://127.0.0.1:5550``: the sonar tile link of ``[links]``
    (:func:`hw.open_links` always connects it; the sonar processor binds)."""
    return f"ZeroMQ {link.socket_type.upper()} connected to {link.endpoint}"


def startup_lines(settings, links: dict, service, *, model_path: str | None, calibrator,
                  recording: Path | None) -> list[str]:
    """What ``run`` says at start (INFO): endpoints and socket types, each link configured or
    not, the contact and snapshot endpoints, the recording and the model in use."""
    ls = settings.links
    out = []
    sonar = links.get("sonar")
    out.append(f"sonar tiles: {_zmq_link_text(sonar)}" if sonar is not None
               else "sonar tiles: not configured (links.sonar_endpoint)")
    out.append(f"NMEA INS: {ls.nmea_url} at {ls.nmea_baudrate} baud" if "nmea" in links
               else "NMEA INS: not configured (links.nmea_url)")
    out.append(f"CAN: {ls.can_interface} channel {ls.can_channel}" if "can" in links
               else "CAN: not configured (links.can_interface)")
    pub = service.publisher
    out.append(f"contacts and heartbeats: ZeroMQ PUB bound to {pub.endpoint}" if pub is not None
               else "contacts and heartbeats: not published (links.publish_endpoint)")
    snap = service.snapshot_server
    out.append(f"late joiners (snapshot endpoint): ZeroMQ ROUTER bound to {snap.endpoint}" if snap is not None
               else "late joiners (snapshot endpoint): off (links.snapshot_endpoint)")
    out.append(f"recording the links to {recording}" if recording is not None
               else "not recording the links (--no-record): no resume after a crash")
    model = f"the model in {model_path}" if model_path else "the shipped model"
    if calibrator is None:
        out.append(f"model: {model}; on-line calibration off")
    else:
        out.append(f"model: {model} until the on-line calibration from the first {calibrator.n_tiles} tiles "
                   f"is ready, then the on-line model")
    return out


def exit_line(summary: dict, *, live_contacts: int, uptime_s: float) -> str:
    """The one line ``run`` logs at exit, from :meth:`NodeService.summary`."""
    from .replay import dropped_text, notes_text

    return (f"stopped after {uptime_s:.0f} s: {summary['tiles_in']} tiles in, {summary['tiles_done']} done, "
            f"{summary['tiles_rejected']} rejected, {dropped_text(summary)}; {live_contacts} live contacts "
            f"({summary['contacts']} ever); "
            f"{summary['snapshots']} snapshots; {summary['model']['short']}{notes_text(summary)}")
