"""No input can make the node write outside its data directory (issue 10).

The node runs in a subprocess with a Python audit hook (PEP 578) that records every file
opened for writing and every mkdir, rename, remove, truncate, rmtree, link and chmod, with
the absolute path. It is fed tiles whose mission names are path traversals, absolute paths,
NUL bytes and long strings, and NMEA and CAN records that carry such strings. Every write
must land under the data directory (bytecode caches of Python itself aside)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import msgpack
import zmq

from atr_node.io.atrlog import AtrLogWriter, read_atrlog

REPO = Path(__file__).resolve().parents[2]

HOOK = r"""
import json, os, sys
events = []
WRITE = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND
PATH_EVENTS = ("os.mkdir", "os.rename", "os.remove", "os.rmdir", "os.truncate", "shutil.rmtree", "os.symlink",
               "os.link", "os.chmod", "os.chown", "os.utime", "os.mkfifo", "os.mknod")

DIR_FD = {"os.mkdir": (2,), "os.remove": (1,), "os.rmdir": (1,), "os.rename": (2, 3), "os.chmod": (2,),
          "shutil.rmtree": (1,), "os.symlink": (2, 2), "os.link": (2, 3), "os.utime": (3,), "os.chown": (3,)}

def _abs(p, dir_fd=None):
    try:
        p = os.fsdecode(p)
        if isinstance(dir_fd, int) and not os.path.isabs(p):  # relative to an open folder (rmtree does this)
            p = os.path.join(os.readlink(f"/proc/self/fd/{dir_fd}"), p)
        return os.path.abspath(p)
    except (TypeError, ValueError, OSError):
        return repr(p)

def hook(event, args):
    if event == "open":
        path, mode, flags = (tuple(args) + (None, None, None))[:3]
        if path is None or isinstance(path, int):
            return
        w = (isinstance(mode, str) and any(c in mode for c in "wax+")) or (isinstance(flags, int) and flags & WRITE)
        if w:
            events.append(["open", _abs(path)])
    elif event in PATH_EVENTS:
        fds = DIR_FD.get(event, ())
        for i, a in enumerate(args[:2]):
            if isinstance(a, (str, bytes, os.PathLike)):
                k = fds[i] if i < len(fds) else None
                events.append([event, _abs(a, args[k] if k is not None and k < len(args) else None)])

out = sys.argv[1]
sys.path.insert(0, sys.argv[2])
sys.addaudithook(hook)
from atr_node.cli import main
rc = 1
try:
    rc = main(sys.argv[3:])
finally:
    seen = list(events)
    with open(out, "w") as fh:
        json.dump(seen, fh)
sys.exit(rc)
"""

EVIL = ["../../../../../tmp/atr-escape-{u}", "/tmp/atr-escape-{u}", "a/../../../atr-escape-{u}",
        "..\\..\\atr-escape-{u}", "atr-escape-{u}\x00/etc/passwd", "~/atr-escape-{u}", "x" * 5000 + "{u}"]


def _evil_tiles(maps: list[dict], u: str) -> list[dict]:
    out = []
    for i, m in enumerate(maps):
        m = dict(m)
        m["mission"] = EVIL[i % len(EVIL)].format(u=u)
        out.append(m)
    return out


def _outside(events: list, data: Path) -> list:
    root = str(data.resolve())
    return [e for e in events if not (e[1] == root or e[1].startswith(root + os.sep))
            and "__pycache__" not in e[1] and e[1] != os.devnull]


def _run_hooked(args: list[str], audit: Path, cwd: Path, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", HOOK, str(audit), str(REPO), *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def test_replay_of_hostile_records_writes_only_under_its_data_directory(small_mission, tmp_path):
    settings, cfg, files = small_mission
    u = uuid.uuid4().hex[:8]
    data, cwd = tmp_path / "data", tmp_path / "cwd"
    data.mkdir()
    cwd.mkdir()
    log = tmp_path / "hostile.atrlog"
    recs = list(read_atrlog(files.atrlog))
    tiles = _evil_tiles([r.msg for r in recs if r.link == "sonar"], u)
    k = 0
    with AtrLogWriter(log) as w:
        for r in recs:
            if r.link == "sonar":
                w.write(r.t, "sonar", tiles[k])
                k += 1
            else:
                w.write_record(r)
            if r.link == "nmea" and k % 5 == 0:
                w.write(r.t, "nmea", f"$GPTXT,01,01,02,../../atr-escape-{u}*00".encode())
    audit = tmp_path / "audit.json"
    proc = _run_hooked(["replay", str(log), "--config", str(cfg), "--online-calibration", "off", "--workers", "0",
                        "--publish", "none", "--state-dir", str(data / "state"),
                        "--contacts-out", str(data / "contacts.jsonl"), "--summary", str(data / "summary.json"),
                        "--quiet"], audit, cwd)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-3000:]
    events = json.loads(audit.read_text())
    assert any("contacts.jsonl" in e[1] for e in events) and any("snap-" in e[1] for e in events)  # the hook saw writes
    assert _outside(events, data) == []
    summary = json.loads((data / "summary.json").read_text())
    assert summary["tiles_in"] == len(tiles) and summary["contacts"] > 0  # the hostile names were processed
    assert not list(tmp_path.rglob(f"*atr-escape-{u}*")) and not list(Path("/tmp").glob(f"atr-escape-{u}*"))


def test_live_node_fed_hostile_tiles_writes_only_under_its_data_directory(small_mission, tmp_path):
    settings, _, files = small_mission
    u = uuid.uuid4().hex[:8]
    data, cwd = tmp_path / "data", tmp_path / "cwd"
    cwd.mkdir()
    ctx = zmq.Context.instance()
    push = ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    port = push.bind_to_random_port("tcp://127.0.0.1")
    cfg = tmp_path / "live.toml"
    cfg.write_text(f'[links]\nsonar_endpoint = "tcp://127.0.0.1:{port}"\nnmea_url = "loop://"\n'
                   f'publish_endpoint = "tcp://127.0.0.1:*"\n[node]\ndata_dir = "{data}"\nsnapshot_every_tiles = 2\n'
                   f'[calibration]\nonline = false\n')
    audit = tmp_path / "audit.json"
    proc = _run_hooked(["run", "--config", str(cfg)], audit, cwd)
    try:
        tiles = _evil_tiles([r.msg for r in read_atrlog(files.atrlog) if r.link == "sonar"][:12], u)
        recordings = data / "recordings"
        deadline = time.monotonic() + 60
        sent = 0
        while time.monotonic() < deadline:  # until the node has recorded every tile
            if sent < len(tiles):
                push.send(msgpack.packb(tiles[sent], use_bin_type=True))
                sent += 1
            recs = [r for f in recordings.glob("*.atrlog") for r in read_atrlog(f, allow_empty=True)] if recordings.is_dir() else []
            if sent == len(tiles) and sum(r.link == "sonar" for r in recs) == len(tiles):
                break
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        push.close()
    assert proc.returncode == 0, err[-3000:]
    events = json.loads(audit.read_text())
    assert any(e[1].endswith(".atrlog") for e in events) and any("snap-" in e[1] for e in events)
    assert _outside(events, data) == []
    assert sum(r.link == "sonar" for f in recordings.glob("*.atrlog") for r in read_atrlog(f)) == len(tiles)
    assert not list(tmp_path.rglob(f"*atr-escape-{u}*")) and not list(Path("/tmp").glob(f"atr-escape-{u}*"))
