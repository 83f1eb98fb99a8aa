"""State directories (issue 21, item 6): keyed by the recording, robust to damage.

Before: a ``--state-dir`` left by another recording logged "starting afresh" and then kept the
old evidence (``leg 0 is already closed`` errors, the old mission's contacts, exit 0); a
damaged snapshot ended the replay (``BadZipFile``; ``UnicodeDecodeError`` in
``read_current``). Now another recording's state is moved to ``previous/`` and the node starts
truly afresh; a damaged snapshot falls back to the previous one, or starts afresh, with one
warning.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from atr_node.config import load_settings
from atr_node.node import state as node_state
from atr_node.simulation.mission import generate_mission

SMALL = """
[simulation]
mission_legs = 2
mission_leg_length_m = 70.0
mission_swath_m = 30.0
mission_targets = 4
mission_tile_pings = 128
mission_clutter_per_km2 = 500.0

[node]
snapshot_every_tiles = 4
"""


@pytest.fixture(scope="module")
def two_missions(tmp_path_factory):
    """(config, mission A, mission B): two 24-tile missions of other seeds."""
    d = tmp_path_factory.mktemp("state_dirs")
    cfg = d / "small.toml"
    cfg.write_text(SMALL)
    settings = load_settings(cfg)
    return cfg, generate_mission(settings, d / "a", seed=11), generate_mission(settings, d / "b", seed=12)


def _replay(cfg: Path, log: Path, out: Path, state: Path | None = None) -> tuple[subprocess.CompletedProcess, list]:
    contacts = out / f"contacts-{len(list(out.glob('contacts-*')))}.jsonl"
    cmd = [sys.executable, "-m", "atr_node", "replay", str(log), "--config", str(cfg), "--publish", "none",
           "--online-calibration", "off", "--speed", "max", "--contacts-out", str(contacts)]
    if state is not None:
        cmd += ["--state-dir", str(state)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    got = [json.loads(line) for line in contacts.read_text().splitlines()] if r.returncode == 0 else None
    return r, got


def _warnings(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if " WARNING " in line]


@pytest.fixture(scope="module")
def state_of_a(two_missions, tmp_path_factory):
    """A state directory left by a whole replay of mission A (its final snapshot and the
    previous one), and A's contacts from a clean run."""
    cfg, a, _ = two_missions
    d = tmp_path_factory.mktemp("state_of_a")
    r, clean = _replay(cfg, a.atrlog, d)
    assert r.returncode == 0, r.stderr
    r, with_state = _replay(cfg, a.atrlog, d, d / "state")
    assert r.returncode == 0, r.stderr
    assert with_state == clean
    assert len(list((d / "state").glob("snap-*"))) == 2  # the current one and the previous one
    return d / "state", clean


def test_state_dir_of_another_recording_is_set_aside_and_the_node_starts_truly_afresh(two_missions, state_of_a,
                                                                                     tmp_path):
    cfg, a, b = two_missions
    state = tmp_path / "state"
    shutil.copytree(state_of_a[0], state)
    old = sorted(p.name for p in state.iterdir())
    r_clean, b_clean = _replay(cfg, b.atrlog, tmp_path)
    r, b_got = _replay(cfg, b.atrlog, tmp_path, state)
    assert r_clean.returncode == 0 and r.returncode == 0, r.stderr
    assert "already closed" not in r.stderr and " ERROR " not in r.stderr
    assert b_got == b_clean  # B's contacts, nothing of A's evidence
    warns = _warnings(r.stderr)
    assert len(warns) == 1, r.stderr
    assert str(a.atrlog) in warns[0] and str(b.atrlog) in warns[0] and "previous" in warns[0]
    assert sorted(p.name for p in (state / "previous").iterdir()) == old  # A's state kept, whole
    # and the state is now B's: a replay of B resumes from it, without a warning of that kind
    r2, b_again = _replay(cfg, b.atrlog, tmp_path, state)
    assert r2.returncode == 0 and b_again == b_clean
    assert not any("is of recording" in w for w in _warnings(r2.stderr))


def test_same_recording_under_another_path_still_resumes(two_missions, state_of_a, tmp_path):
    """The identity is the recording's content, not its path: a recording copied elsewhere
    resumes (with the old path-only check it would have been "another recording")."""
    cfg, a, _ = two_missions
    state = tmp_path / "state"
    shutil.copytree(state_of_a[0], state)
    moved = tmp_path / "copy.atrlog"
    shutil.copy(a.atrlog, moved)
    r, got = _replay(cfg, moved, tmp_path, state)
    assert r.returncode == 0 and got == state_of_a[1]
    assert "resumed from snapshot" in r.stderr and not (state / "previous").exists()


def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def _garble(p: Path) -> None:
    b = bytearray(p.read_bytes())
    mid = len(b) // 3
    b[mid:mid + 64] = bytes(x ^ 0x5A for x in b[mid:mid + 64])
    p.write_bytes(bytes(b))


def _not_utf8(p: Path) -> None:
    p.write_bytes(b"\xff\xfe\x00snap-\x80")


def _current(state: Path) -> Path:
    return state / (state / "CURRENT").read_text().strip()


def _older(state: Path) -> Path:
    return min(state.glob("snap-*"), key=lambda f: int(f.name.split("-")[1]))


DAMAGE = {
    "CURRENT not UTF-8": lambda s: _not_utf8(s / "CURRENT"),
    "CURRENT garbled": lambda s: _garble(s / "CURRENT"),
    "CURRENT removed": lambda s: (s / "CURRENT").unlink(),
    "node.npz truncated": lambda s: _truncate(_current(s) / "node.npz"),
    "node.npz garbled": lambda s: _garble(_current(s) / "node.npz"),
    "grid.npz truncated": lambda s: _truncate(_current(s) / "grid.npz"),
    "grid.npz garbled": lambda s: _garble(_current(s) / "grid.npz"),
    "node.npz empty": lambda s: (_current(s) / "node.npz").write_bytes(b""),
    "both snapshots damaged": lambda s: (_truncate(_older(s) / "grid.npz"), _garble(_current(s) / "node.npz")),
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_damaged_snapshot_falls_back_with_one_warning_and_gives_the_clean_contacts(two_missions, state_of_a,
                                                                                   tmp_path, damage):
    cfg, a, _ = two_missions
    state = tmp_path / "state"
    shutil.copytree(state_of_a[0], state)
    DAMAGE[damage](state)
    r, got = _replay(cfg, a.atrlog, tmp_path, state)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and " ERROR " not in r.stderr
    assert got == state_of_a[1]  # the clean run's contacts (resumed from the previous, or afresh)
    warns = [w for w in _warnings(r.stderr) if "resumed from snapshot" not in w]
    if damage == "CURRENT removed":
        assert len(warns) == 1 and "resuming from" in warns[0]  # the newest snapshot there, named
    elif damage == "both snapshots damaged":
        assert len(warns) == 1 and "starting afresh" in warns[0] and "previous" in warns[0], r.stderr
        assert "resumed from snapshot" not in r.stderr
    else:
        assert len(warns) == 1 and "resuming from" in warns[0], r.stderr
    # the directory holds readable snapshots again: a strict load of the current one works
    assert node_state.read_snapshot(node_state.read_current(state)).meta["position"] > 0
