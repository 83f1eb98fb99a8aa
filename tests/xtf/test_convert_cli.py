"""``atr-node convert`` both ways, through the real command line."""

from __future__ import annotations

import subprocess
import sys

import pytest

from atr_node.cli import main
from atr_node.io.atrlog import read_atrlog
from atr_node.io.xtf import XtfReader
from atr_node.records.tile import Tile


def test_convert_both_ways(iver2, tmp_path, capsys):
    log = tmp_path / "iver2.atrlog"
    assert main(["convert", str(iver2), str(log), "--tile-pings", "128", "--leg", "3"]) == 0
    out = capsys.readouterr().out
    assert "sonar 461" in out and "pings 461" in out and "wrote 1421 records" in out
    records = list(read_atrlog(log))
    tiles = [Tile.from_map(r.msg) for r in records if r.link == "sonar"]
    assert len(tiles) == 2 * 5 and {t.leg for t in tiles} == {3} and max(t.rows for t in tiles) == 128
    back = tmp_path / "back.xtf"
    assert main(["convert", str(log), str(back)]) == 0
    out = capsys.readouterr().out
    assert "wrote 461 pings from 10 tiles" in out and "nmea records 1411" in out
    again = [Tile.from_map(r.msg) for r in XtfReader(back, tile_pings=128) if r.link == "sonar"]
    assert [(t.side, t.seq, t.leg, t.rows) for t in again] == [(t.side, t.seq, t.leg, t.rows) for t in tiles]


def test_convert_nav_only_file_is_refused(nav_only, tmp_path, capsys):
    """A recording with navigation and no sonar tile is bad input for convert (issue 20): one
    line, exit 1, no output file."""
    assert main(["convert", str(nav_only), str(tmp_path / "nav.atrlog")]) == 1
    err = capsys.readouterr().err
    assert f"{nav_only}: no sonar tile in " in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (["a.xtf", "b.txt"], "unknown recording type '.txt'"),
    (["a.atrlog", "b.atrlog"], "both are .atrlog"),
    (["missing.xtf", "b.atrlog"], "missing.xtf: no such file"),
    (["in.atrlog", "no/such/dir/out.xtf"], "out.xtf: No such file or directory"),
])
def test_convert_errors_say_what_and_where(tmp_path, capsys, args, message):
    (tmp_path / "in.atrlog").write_bytes(b"")
    args = [str(tmp_path / a) for a in args]
    assert main(["convert", *args]) == 1
    assert message in capsys.readouterr().err


def test_convert_help_runs_as_a_program():
    out = subprocess.run([sys.executable, "-m", "atr_node", "convert", "--help"], capture_output=True, text=True,
                         check=True).stdout
    assert "--tile-pings" in out and ".xtf" in out
