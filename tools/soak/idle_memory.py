#!/usr/bin/env python3
"""Resident memory of an idle ``atr-node run``: the main process and its worker processes.

Starts the node on loopback (free ports, no INS, no CAN, nothing sending tiles) for each
``node.warm_up_mpx`` asked, waits until its memory stops growing (the warm-up done), reads
VmRSS and VmHWM from ``/proc/<pid>/status`` of the node and of each child process, then stops
it with SIGINT. RSS is what ``ps -o rss`` shows: shared pages (libraries, the shared-memory
tile slots) count in each process; the total PSS (``smaps_rollup``) counts them once.

Examples
--------
    python tools/soak/idle_memory.py                       # the default warm-up (8 Mpx) and none
    python tools/soak/idle_memory.py --warm-up-mpx 8 2 0.05 0 --json idle.json
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _status_kb(pid: int, key: str) -> int:
    """``VmRSS`` / ``VmHWM`` of ``pid`` in kB (0 when the process is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _pss_kb(pid: int) -> int:
    """Proportional set size of ``pid`` in kB (``/proc/<pid>/smaps_rollup``): shared pages
    divided among the processes that map them, so the node's total is not counted twice."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _children(pid: int) -> list[int]:
    """Direct and indirect child processes of ``pid`` (``/proc/<pid>/task/*/children``)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                kids = [int(x) for x in (task / "children").read_text().split()]
            except OSError:
                continue
            out += kids
            todo += kids
    return out


def measure(warm_up_mpx: float, *, settle_s: float, max_wait_s: float) -> dict:
    """Start an idle node with ``node.warm_up_mpx = warm_up_mpx``; its memory once settled, in MB."""
    with tempfile.TemporaryDirectory(prefix="atr-idle-") as tmp:
        cfg = Path(tmp) / "node.toml"
        ports = [_free_port() for _ in range(3)]
        cfg.write_text(f"""
[links]
sonar_endpoint = "tcp://127.0.0.1:{ports[0]}"
nmea_url = ""
can_interface = ""
publish_endpoint = "tcp://127.0.0.1:{ports[1]}"
snapshot_endpoint = "tcp://127.0.0.1:{ports[2]}"

[node]
data_dir = "{Path(tmp) / 'data'}"
warm_up_mpx = {warm_up_mpx}
""")
        proc = subprocess.Popen([sys.executable, "-m", "atr_node", "run", "--config", str(cfg),
                                 "--online-calibration", "off"], cwd=REPO, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        try:
            t0 = time.monotonic()
            last, stable_since = -1, time.monotonic()
            while time.monotonic() - t0 < max_wait_s and proc.poll() is None:
                time.sleep(0.5)
                total = _status_kb(proc.pid, "VmRSS") + sum(_status_kb(c, "VmRSS") for c in _children(proc.pid))
                if abs(total - last) > 1024:  # still growing (or shrinking) by more than 1 MB
                    last, stable_since = total, time.monotonic()
                elif time.monotonic() - stable_since >= settle_s:
                    break
            kids = _children(proc.pid)
            row = {"warm_up_mpx": warm_up_mpx,
                   "main_rss_mb": _status_kb(proc.pid, "VmRSS") / 1024,
                   "main_peak_mb": _status_kb(proc.pid, "VmHWM") / 1024,
                   "children_rss_mb": [_status_kb(c, "VmRSS") / 1024 for c in kids],
                   "children_peak_mb": [_status_kb(c, "VmHWM") / 1024 for c in kids],
                   "settled_after_s": round(stable_since - t0, 1)}
            row["total_rss_mb"] = row["main_rss_mb"] + sum(row["children_rss_mb"])
            row["total_pss_mb"] = (_pss_kb(proc.pid) + sum(_pss_kb(c) for c in kids)) / 1024
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc.returncode not in (0, None):
            raise SystemExit(f"idle_memory: the node exited {proc.returncode}: {proc.stderr.read()[-2000:]}")
        return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--warm-up-mpx", type=float, nargs="+", default=[8.0, 0.0],
                    help="node.warm_up_mpx values to measure (default: 8 0)")
    ap.add_argument("--settle-s", type=float, default=5.0, help="memory unchanged this long = idle (default 5)")
    ap.add_argument("--max-wait-s", type=float, default=120.0, help="give up waiting for it to settle (default 120)")
    ap.add_argument("--json", metavar="FILE", help="also write the rows as JSON")
    args = ap.parse_args(argv)
    rows = [measure(w, settle_s=args.settle_s, max_wait_s=args.max_wait_s) for w in args.warm_up_mpx]
    print(f"{'warm_up_mpx':>11} {'main MB':>8} {'children MB':>22} {'total MB':>9} {'total PSS':>10} "
          f"{'main peak':>10}")
    for r in rows:
        kids = " + ".join(f"{x:.0f}" for x in r["children_rss_mb"]) or "-"
        print(f"{r['warm_up_mpx']:>11g} {r['main_rss_mb']:>8.0f} {kids:>22} {r['total_rss_mb']:>9.0f} "
              f"{r['total_pss_mb']:>10.0f} {r['main_peak_mb']:>10.0f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
