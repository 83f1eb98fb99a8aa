"""The on-vehicle daemon: live links through the pipeline, contacts on ZeroMQ (ICD section 6).

Opens the links of [links] (sonar tiles over ZeroMQ, NMEA INS over serial, CAN), records
everything received to an .atrlog in node.data_dir/recordings (the recording is also the
node's write-ahead log), runs the pipeline in live mode (degrades rather than queueing without
bound), publishes contacts and heartbeats, and snapshots to node.data_dir/state.

On start it resumes from the last snapshot: the records of its previous recording after the
snapshot's position are replayed first, so no accepted tile's evidence is lost across a
crash or a restart. SIGTERM drains, snapshots and exits 0. Under systemd (Type=notify) it
reports READY and feeds the watchdog.
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

    settings = load_settings(args.config)
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
        meta_folder = node_state.read_current(state_dir)
        if meta_folder is not None:
            meta = node_state.load(state_dir, service.pipeline)
            service.sync_contact_view()  # late joiners get the restored contacts, then the replayed ones
            prev = Path(meta.get("source", ""))
            if prev.is_file():
                n = 0
                for rec in itertools.islice(read_atrlog(prev), int(meta["position"]), None):
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
        log.warning("running: links %s, publishing on %s, recording to %s", ", ".join(links),
                    settings.links.publish_endpoint, recording)
        t0 = time.monotonic()
        service.run_live(link)
        link.shutdown()
        log.warning("stopped after %.0f s: %s", time.monotonic() - t0, service.summary())
        return 0
    finally:
        service.close()
