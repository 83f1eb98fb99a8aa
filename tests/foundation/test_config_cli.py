"""Configuration (typed, validated TOML) and the atr-node command skeleton."""

from __future__ import annotations

import subprocess
import sys

import pytest

from atr_node.cli import COMMANDS, _is_built, main
from atr_node.config import Settings, default_config_path, load_settings
from atr_node.errors import ConfigError


def test_default_file_equals_built_in_defaults():
    s = load_settings(default_config_path())
    assert s == Settings()
    assert s.sensor.frequency_hz == 120e3 and s.sensor.dr_m == 0.1 and s.sensor.altitude_m == 14.0
    assert s.source.endswith("default.toml")


def write(tmp_path, text, name="c.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("text,key,fragment", [
    ("[sensor]\nfrequncy_hz = 1.0\n", "sensor.frequncy_hz", "unknown key"),
    ("[sonar]\nx = 1\n", "sonar", "unknown key"),
    ("top = 1\n", "top", "unknown key"),
    ("[sensor]\nfrequency_hz = \"high\"\n", "sensor.frequency_hz", "expected a number"),
    ("[sensor]\nn_rx = 2.5\n", "sensor.n_rx", "expected an integer"),
    ("[sensor]\nsas = 1\n", "sensor.sas", "expected true or false"),
    ("[sensor]\nn_rx = true\n", "sensor.n_rx", "expected an integer"),
    ("[mission]\nframe = \"mercator\"\n", "mission.frame", "expected one of"),
    ("[detectors]\nenabled = [\"mf\", \"cnn\"]\n", "detectors.enabled", "unknown detector"),
    ("[detectors]\nenabled = \"mf\"\n", "detectors.enabled", "expected a list"),
    ("[detectors]\nrelocate = [\"cnn\"]\n", "detectors.relocate", "unknown detector"),
    ("[detectors]\nrelocate = [\"mf\"]\n", "detectors.relocate", "the matched filter places the others"),
    ("[detectors]\nrelocate = [\"lac\", \"lac\"]\n", "detectors.relocate", "lists a detector twice"),
    ("[detectors.threshold]\nmf = \"x\"\n", "detectors.threshold.mf", "expected a number"),
    ("[detectors.threshold]\ncnn = 1.0\n", "detectors.threshold.cnn", "unknown key"),
    ("sensor = 5\n", "sensor", "expected a table"),
    ("[sensor]\naltitude_m = -1.0\n", "sensor.altitude_m", "must be > 0"),
    ("[fusion]\neps = 0.5\n", "fusion.eps", "must be in"),
    ("[calibration]\nlook_z_min = nan\n", "calibration.look_z_min", "must be a number below inf"),
    ("[calibration]\nlook_z_min = inf\n", "calibration.look_z_min", "must be a number below inf"),
    ("[calibration]\nlook_weights = \"max\"\n", "calibration.look_weights", "expected one of"),
    ("[calibration]\nclip_headroom_db = nan\n", "calibration.clip_headroom_db", "must be a finite number of dB"),
    ("[node]\nheartbeat_s = 5.0\n", "node.heartbeat_s", "at least once a second"),
    ("[mission]\norigin_lat_deg = 44.0\n", "mission.origin_lat_deg", "together"),
])
def test_bad_keys_name_file_and_key(tmp_path, text, key, fragment):
    p = write(tmp_path, text)
    with pytest.raises(ConfigError) as ei:
        load_settings(p)
    msg = str(ei.value)
    assert ei.value.key == key, msg
    assert str(p) in msg and key in msg and fragment in msg


def test_partial_file_keeps_defaults_and_ints_become_floats(tmp_path):
    s = load_settings(write(tmp_path, "[sensor]\naltitude_m = 10\n[detectors]\nenabled = [\"z\"]\n"))
    assert s.sensor.altitude_m == 10.0 and isinstance(s.sensor.altitude_m, float)
    assert s.detectors.enabled == ("z",)
    assert s.fusion == Settings().fusion


def test_include_and_include_loop(tmp_path):
    write(tmp_path, "[sensor]\naltitude_m = 9.0\ndr_m = 0.05\n", "base.toml")
    s = load_settings(write(tmp_path, "include = \"base.toml\"\n[sensor]\ndr_m = 0.2\n"))
    assert s.sensor.altitude_m == 9.0 and s.sensor.dr_m == 0.2
    write(tmp_path, "include = \"b.toml\"\n", "a.toml")
    write(tmp_path, "include = \"a.toml\"\n", "b.toml")
    with pytest.raises(ConfigError, match="include loop"):
        load_settings(tmp_path / "a.toml")


def test_missing_and_invalid_toml(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_settings(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_settings(write(tmp_path, "[sensor\n"))


def test_cli_help_and_not_built(capsys, monkeypatch):
    with pytest.raises(SystemExit) as ei:
        main(["--help"])
    assert ei.value.code == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert name in out
    # a subcommand whose module does not exist says so and exits 2, it does not pretend
    monkeypatch.setitem(COMMANDS, "future", ("a command of a later issue", "some later"))
    assert not _is_built("future")
    assert main(["future"]) == 2
    assert "not built yet" in capsys.readouterr().err
    for name in COMMANDS:  # every subcommand has --help
        with pytest.raises(SystemExit) as ei:
            main([name, "--help"])
        assert ei.value.code == 0


def test_cli_info_reports_bad_config(tmp_path, capsys):
    p = write(tmp_path, "[fusion]\ncell = 1\n")
    assert main(["info", "--config", str(p)]) == 1
    err = capsys.readouterr().err
    assert "fusion.cell" in err and str(p) in err
    assert main(["info"]) == 0


def test_console_entry_point_runs():
    r = subprocess.run([sys.executable, "-m", "atr_node", "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "atr-node" in r.stdout


def test_a_command_loads_only_its_own_module():
    """``atr-node CMD ...`` imports CMD's module and no other command's (a command's module may
    pull in scipy and OpenCV: the error path and --help of a light command stay quick), the
    top-level --help imports none, and every command's parser is still the full one."""
    probe = ("import sys, contextlib, io\n"
             "from atr_node.cli import main\n"
             "with contextlib.redirect_stdout(io.StringIO()):\n"
             "    try:\n"
             "        main(sys.argv[1:])\n"
             "    except SystemExit:\n"
             "        pass\n"
             "print(' '.join(sorted(m.rsplit('.', 1)[1] for m in sys.modules\n"
             "                      if m.startswith('atr_node.commands.') and not m.rsplit('.', 1)[1].startswith('_'))))\n")

    def loaded(*argv):
        r = subprocess.run([sys.executable, "-c", probe, *argv], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        return r.stdout.split()

    assert loaded("--help") == []
    assert loaded("-v", "export", "--help") == ["export"]
    assert loaded("info") == ["info"]
    assert loaded("bogus") == []  # argparse's "invalid choice", from the one-line listing
    # the lazy listing keeps each command's own parser whole when it is the one chosen
    from atr_node.cli import _chosen, build_parser

    assert _chosen(["-v", "-v", "replay", "x.atrlog"]) == "replay"
    assert _chosen(["--version"]) is None and _chosen(["--", "replay"]) is None and _chosen(["nope"]) is None
    full, lazy = build_parser(), build_parser(only="convert")
    argv = ["convert", "a.xtf", "b.atrlog"]
    assert vars(full.parse_args(argv)) == vars(lazy.parse_args(argv))
