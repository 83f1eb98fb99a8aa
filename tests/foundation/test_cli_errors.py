"""Every command fails on bad input in one line, with exit status 1, and leaves no output
behind (issue 20, item 1); every --help documents the exit codes and shows no reST markers.

The error paths run the real program (``python -m atr_node``) in a fresh folder, on real
files (a small generated mission, a text file named .atrlog, an empty one, a recording of
navigation only) and real sockets (a port held by another socket), and check: the exit
status, exactly one line on stderr naming the file or option, no traceback, and no file left
in the folder besides the inputs.
"""

from __future__ import annotations

import dataclasses
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from atr_node.cli import COMMANDS, EXIT_STATUS, _is_built, main
from atr_node.commands._endpoints import check_endpoint, endpoint_problem
from atr_node.config import load_settings
from atr_node.errors import AtrError
from atr_node.io.atomic import atomic_open, atomic_path
from atr_node.io.atrlog import AtrLogWriter

ROOT = Path(__file__).resolve().parents[2]
NMEA = b"$GPZDA,120000.00,01,01,2024,00,00*6A\r\n"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """Input files, in a folder of their own (the commands run elsewhere)."""
    from atr_node.simulation.mission import generate_mission

    d = tmp_path_factory.mktemp("inputs")
    s = load_settings(None)
    s = s.replace(simulation=dataclasses.replace(s.simulation, mission_legs=2, mission_leg_length_m=40.0,
                                                 mission_swath_m=20.0, mission_targets=2, mission_tile_pings=64))
    files = generate_mission(s, d / "mission", seed=1, name="tiny")
    text = d / "readme.atrlog"
    text.write_bytes((ROOT / "README.md").read_bytes()[:20000])
    empty = d / "empty.atrlog"
    empty.write_bytes(b"")
    nav = d / "nav.atrlog"
    with AtrLogWriter(nav) as w:
        for i in range(12):
            w.write(1.7e9 + i, "nmea", NMEA)
    return {"mission": Path(files.atrlog), "truth": Path(files.truth), "text": text, "empty": empty, "nav": nav}


@pytest.fixture
def busy_port():
    """A TCP port on 127.0.0.1 held by a listening socket for the test."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    yield s.getsockname()[1]
    s.close()


def _fails_in_one_line(cwd: Path, *args: str, expect: str, status: int = 1) -> str:
    """Run ``atr-node ARGS`` in ``cwd``; check the one-line failure and that ``cwd`` is as before."""
    before = sorted(p.name for p in cwd.iterdir())
    r = subprocess.run([sys.executable, "-m", "atr_node", *args], cwd=cwd, capture_output=True, text=True,
                       timeout=120)
    lines = r.stderr.splitlines()
    assert r.returncode == status, r.stderr
    assert len(lines) == 1, r.stderr
    assert "Traceback" not in r.stderr
    assert lines[0].startswith(f"atr-node {args[0]}: error: "), lines[0]
    assert expect in lines[0], lines[0]
    assert sorted(p.name for p in cwd.iterdir()) == before, "output left behind after an error"
    return lines[0]


OUTPUTS = ("--contacts-out", "c.jsonl", "--detections-out", "d.jsonl", "--summary", "s.json")


@pytest.mark.parametrize("which, expect", [
    ("missing", "missing.atrlog: cannot open: No such file"),
    ("text", "readme.atrlog: no valid record in 20000 bytes"),
    ("empty", "empty.atrlog: empty file"),
    ("nav", "nav.atrlog: no sonar tile in 12 records"),
])
def test_replay_refuses_what_is_not_a_recording_of_tiles(inputs, tmp_path, which, expect):
    path = inputs.get(which, tmp_path.parent / "missing.atrlog")
    _fails_in_one_line(tmp_path, "replay", str(path), "--publish", "none", *OUTPUTS, expect=expect)


@pytest.mark.parametrize("endpoint, expect", [
    ("foo", "--publish 'foo': no transport"),
    ("tcp://127.0.0.1", "--publish 'tcp://127.0.0.1': no port"),
    ("tcp://127.0.0.1:99999", "port 99999 out of range 1-65535"),
    ("udp://127.0.0.1:5560", "unknown transport 'udp://'"),
])
def test_replay_refuses_a_bad_publish_endpoint(inputs, tmp_path, endpoint, expect):
    _fails_in_one_line(tmp_path, "replay", str(inputs["mission"]), "--publish", endpoint, *OUTPUTS, expect=expect)


def test_replay_on_a_port_in_use(inputs, tmp_path, busy_port):
    _fails_in_one_line(tmp_path, "replay", str(inputs["mission"]), "--publish", f"tcp://127.0.0.1:{busy_port}",
                       "--online-calibration", "off", *OUTPUTS, expect="Address already in use")


def test_replay_refuses_a_bad_speed(inputs, tmp_path):
    _fails_in_one_line(tmp_path, "replay", str(inputs["mission"]), "--publish", "none", "--speed", "-2",
                       expect="--speed '-2': expected a factor > 0 or 'max'")


def _run_config(path: Path, data: Path, publish: str) -> Path:
    path.write_text(f'[node]\ndata_dir = "{data}"\nwarm_up_mpx = 0.1\n\n'
                    f'[links]\npublish_endpoint = "{publish}"\nsnapshot_endpoint = ""\n')
    return path


def test_run_on_a_port_in_use(tmp_path, busy_port):
    cfg = _run_config(tmp_path.parent / f"{tmp_path.name}-run.toml", tmp_path.parent / f"{tmp_path.name}-data",
                      f"tcp://127.0.0.1:{busy_port}")
    _fails_in_one_line(tmp_path, "run", "--config", str(cfg), "--online-calibration", "off",
                       expect="Address already in use")


def test_run_refuses_a_port_out_of_range(tmp_path):
    cfg = _run_config(tmp_path.parent / f"{tmp_path.name}-run.toml", tmp_path.parent / f"{tmp_path.name}-data",
                      "tcp://127.0.0.1:99999")
    line = _fails_in_one_line(tmp_path, "run", "--config", str(cfg), expect="port 99999 out of range")
    assert "links.publish_endpoint" in line and cfg.name in line


@pytest.mark.parametrize("source, expect", [
    (("--log", "{missing}"), "missing.atrlog: cannot open: No such file"),
    (("--log", "{text}"), "readme.atrlog: no valid record"),
    (("--log", "{nav}"), "nav.atrlog: no sonar tile in 12 records"),
    (("--contacts", "{missing_jsonl}"), "contacts file"),
    (("--contacts", "{text}"), "readme.atrlog, line 1: not JSON"),
    (("--subscribe", "tcp://127.0.0.1"), "--subscribe 'tcp://127.0.0.1': no port"),
])
def test_evaluate_bad_input_leaves_no_out_folder(inputs, tmp_path, source, expect):
    names = {k: str(v) for k, v in inputs.items()}
    names["missing"] = str(tmp_path.parent / "missing.atrlog")
    names["missing_jsonl"] = str(tmp_path.parent / "missing.jsonl")
    opt, value = source
    _fails_in_one_line(tmp_path, "evaluate", "--truth", str(inputs["truth"]), opt, value.format(**names),
                       "--out", "eval", "--duration", "1", expect=expect)


def test_evaluate_on_a_missing_truth_file(inputs, tmp_path):
    _fails_in_one_line(tmp_path, "evaluate", "--truth", "no-truth.csv", "--log", str(inputs["mission"]),
                       "--out", "eval", expect="truth file no-truth.csv")


@pytest.mark.parametrize("which, out, expect", [
    ("text", "out.xtf", "readme.atrlog: no valid record"),
    ("empty", "out.xtf", "empty.atrlog: empty file"),
    ("nav", "out.xtf", "nav.atrlog: no sonar tile in 12 records"),
    ("mission", "no/such/folder/out.xtf", "no folder no/such/folder"),
])
def test_convert_bad_input_writes_nothing(inputs, tmp_path, which, out, expect):
    _fails_in_one_line(tmp_path, "convert", str(inputs[which]), out, expect=expect)


def test_calibrate_refuses_a_recording_without_tiles(inputs, tmp_path):
    _fails_in_one_line(tmp_path, "calibrate", "--input", str(inputs["nav"]), "--no-plots",
                       expect="nav.atrlog: no sonar tile in 12 records")


@pytest.mark.parametrize("args, expect", [
    (("monitor", "--from", "tcp://127.0.0.1:99999", "--duration", "1"), "--from 'tcp://127.0.0.1:99999': port"),
    (("monitor", "--from", "tcp://127.0.0.1:5560", "--snapshot", "5561", "--duration", "1"), "--snapshot '5561'"),
    (("export", "--from", "foo", "-o", "x.csv", "--duration", "1"), "--from 'foo': no transport"),
    (("export", "--contacts", "missing.jsonl", "-o", "x.csv"), "missing.jsonl"),
    (("exwpt", "--from", "tcp://127.0.0.1", "--port", "loop://", "--duration", "1"), "--from 'tcp://127.0.0.1'"),
    (("batch", "missing.atrlog", "--scheduler", "serial"), "missing.atrlog: cannot open: No such file"),
    (("info", "--config", "missing.toml"), "missing.toml"),
])
def test_operator_and_batch_commands_fail_in_one_line(tmp_path, args, expect):
    _fails_in_one_line(tmp_path, *args, expect=expect)


def test_export_from_a_silent_endpoint_writes_no_empty_file(tmp_path, busy_port):
    # nothing publishes on a port held by a plain TCP listener: no file, not an empty one
    _fails_in_one_line(tmp_path, "export", "--from", f"tcp://127.0.0.1:{busy_port}", "--snapshot", "none",
                       "-o", "x.csv", "--duration", "0.5", expect="nothing received")


def test_simulate_into_an_impossible_folder(tmp_path):
    (tmp_path / "a-file").write_text("")
    _fails_in_one_line(tmp_path, "simulate", "--out", "a-file/mission", expect="a-file")


def test_usage_errors_exit_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "atr_node", "replay"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "usage:" in r.stderr and "Traceback" not in r.stderr


# --- --help of every command -----------------------------------------------------------------

BUILT = [name for name in COMMANDS if _is_built(name)]


@pytest.mark.parametrize("name", BUILT)
def test_help_documents_exit_codes_and_shows_no_markup(name, capsys):
    with pytest.raises(SystemExit) as exc:
        main([name, "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert EXIT_STATUS in text
    for code in ("0    done", "1    bad input", "2    usage", "130  interrupted"):
        assert code in text
    assert "::" not in text.replace("://", "")
    assert "(issue" not in text and "``" not in text


def test_help_as_a_program_has_the_exit_codes():
    out = subprocess.run([sys.executable, "-m", "atr_node", "convert", "--help"], capture_output=True, text=True,
                         check=True, timeout=60).stdout
    assert "exit status:" in out and "130  interrupted" in out


@pytest.mark.parametrize("name", ["replay", "calibrate", "batch", "demo", "monitor"])
def test_one_progress_switch_name(name, capsys):
    with pytest.raises(SystemExit):
        main([name, "--help"])
    text = capsys.readouterr().out
    assert "--no-progress" in text
    assert "--quiet" not in text and "--plain" not in text  # old names: accepted, hidden


@pytest.mark.parametrize("argv", [
    ["replay", "x.atrlog", "--quiet"],
    ["batch", "x.atrlog", "--quiet"],
    ["monitor", "--plain"],
    ["monitor", "--no-progress"],
    ["calibrate", "--no-progress"],
])
def test_old_progress_switch_names_still_parse(argv):
    from atr_node.cli import build_parser

    assert build_parser().parse_args(argv).no_progress is True


# --- the helpers -----------------------------------------------------------------------------

@pytest.mark.parametrize("endpoint", ["tcp://127.0.0.1:5560", "tcp://*:5560", "tcp://127.0.0.1:*",
                                      "tcp://[::1]:1", "tcp://localhost:65535", "ipc:///tmp/atr.sock",
                                      "inproc://contacts", "tcp://eth0;192.168.1.2:5560"])
def test_endpoints_accepted(endpoint):
    assert endpoint_problem(endpoint) is None


@pytest.mark.parametrize("endpoint, why", [
    ("foo", "no transport"), ("tcp://127.0.0.1", "no port"), ("tcp://127.0.0.1:0", "out of range"),
    ("tcp://127.0.0.1:65536", "out of range"), ("tcp://127.0.0.1:99999", "out of range"),
    ("tcp://:5560", "no host"), ("tcp://h:x1", "not a number"), ("ipc://", "nothing after"),
    ("http://h:80", "unknown transport"), ("tcp://[::1:5560", "unbalanced"),
])
def test_endpoints_refused(endpoint, why):
    assert why in endpoint_problem(endpoint)
    with pytest.raises(AtrError, match="--opt"):
        check_endpoint(endpoint, "--opt")


def test_atomic_open_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "contacts.jsonl"
    with pytest.raises(RuntimeError):
        with atomic_open(target, "w") as fh:
            fh.write("half a line")
            raise RuntimeError("failed half way")
    assert list(tmp_path.iterdir()) == []
    with atomic_open(target, "w") as fh:
        fh.write("whole\n")
    assert target.read_text() == "whole\n" and list(tmp_path.iterdir()) == [target]


def test_atomic_path_keeps_the_old_file_on_error(tmp_path):
    target = tmp_path / "model.json"
    target.write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target) as tmp:
            tmp.write_text("new, partial")
            raise KeyboardInterrupt
    assert target.read_text() == "old" and list(tmp_path.iterdir()) == [target]
