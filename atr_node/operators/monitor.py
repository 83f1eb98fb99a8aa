"""The live monitor: a node's heartbeat and contacts on a terminal, redrawn in place.

:func:`render_screen` is a pure function of what a :class:`~atr_node.operators.stream.NodeFollower`
holds (last heartbeat, contact book, counters) and the time, so what the operator sees is
tested on strings. :class:`Monitor` redraws it with ANSI escapes (cursor home, clear to end of
line and of screen: every VT100-compatible terminal, tmux and screen included) at most every
``refresh_s``, and, with a PNG path, rewrites the belief map every ``png_every_s``
(:mod:`atr_node.operators.beliefmap`).

Screen (80 columns or more)::

    atr-node monitor  tcp://127.0.0.1:5560                       2026-11-23 01:02:03 UTC
    node      NOMINAL   up 41.2 s   heartbeat 0.3 s ago
    tiles     in 36  done 36  dropped 0  rejected 0   queue 0   latency p50 8 ms  p99 31 ms
    received  212 heartbeats, 14 contact messages, 0 bad; snapshot: 4 live contacts at seq 9
    contacts  4 live, 1 withdrawn           (sorted by Bel(T))
       id      bel       pl     latitude     longitude  sigma looks  det state detectors  legs    time UTC
       3  0.99756  1.00000   44.080294N     9.850133E   1.5m     1    1 new   smf        0       09:01:46

``time UTC`` is the time of the evidence behind the contact's last message (the recorded time
in a replay). A heartbeat older than ``stale_s`` turns the node line into ``NO HEARTBEAT for N s``.
The ``received`` line ends with how the monitor joined (the node's snapshot, ICD v1.1) when it
asked for one. A PNG asked with a state directory that holds no snapshot yet shows the contacts
alone, and says so, until the node writes one.
"""

from __future__ import annotations

import shutil
import sys
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import TextIO

from ..errors import AtrError
from .stream import NodeFollower, snapshot_text

HOME, CLEAR_EOL, CLEAR_EOS, CLEAR_ALL = "\x1b[H", "\x1b[K", "\x1b[J", "\x1b[2J"
STALE_S = 3.0
"""A node heartbeats at least once a second (ICD section 3): three seconds without is stale."""


_STATE = {"new": "new", "update": "upd", "withdrawn": "GONE"}


def _fmt_deg(v: float, pos: str, neg: str) -> str:
    return f"{abs(v):.6f}{pos if v >= 0 else neg}"


def render_screen(follower: NodeFollower, *, now: float, wall: float | None = None, width: int = 100,
                  max_rows: int = 20, stale_s: float = STALE_S) -> str:
    """The monitor's screen as lines of text (no escapes).

    Parameters
    ----------
    follower : NodeFollower
        Its ``heartbeat``, ``book`` and ``stats``.
    now : float
        ``time.monotonic()`` now (age of the heartbeat); ``wall``: UNIX time now (the clock in
        the title line), default ``time.time()``.
    width, max_rows : int
        Terminal width (lines are cut to it) and contact rows shown (the rest counted).
    """
    wall = time.time() if wall is None else wall
    st, hb, book = follower.stats, follower.heartbeat, follower.book
    clock = datetime.fromtimestamp(wall, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    head = f"atr-node monitor  {follower.endpoint}"
    lines = [head + clock.rjust(max(1, width - len(head)))]
    if hb is None:
        waited = now - st.started_at
        lines.append(f"node      waiting for the first heartbeat ({waited:.0f} s)")
        lines.append("tiles     -")
    else:
        age = now - st.last_heartbeat_at
        status = (f"NO HEARTBEAT for {age:.0f} s (last: {hb['mode']})" if age > stale_s
                  else f"{hb['mode'].upper():9s} up {hb['uptime_s']:.1f} s   heartbeat {age:.1f} s ago")
        lines.append(f"node      {status}")
        lat = hb["latency_ms"]
        lines.append(f"tiles     in {hb['tiles_in']}  done {hb['tiles_done']}  dropped {hb['tiles_dropped']}  "
                     f"rejected {hb['tiles_rejected']}   queue {hb['queue_depth']}   "
                     f"latency p50 {lat['p50']:.0f} ms  p99 {lat['p99']:.0f} ms")
    lines.append(f"received  {st.heartbeats} heartbeats, {st.contacts} contact messages, {st.bad} bad"
                 + (f" (last: {st.last_bad})" if st.bad else "")
                 + (f"; {snapshot_text(st)}" if st.snapshot != "off" else ""))
    rows = book.contacts(include_withdrawn=True)
    lines.append(f"contacts  {book.n_live} live, {book.n_withdrawn} withdrawn   (sorted by Bel(T))")
    lines.append(f"{'id':>5} {'bel':>8} {'pl':>8} {'latitude':>12} {'longitude':>13} {'sigma':>6} {'looks':>5} "
                 f"{'det':>4} {'state':5s} {'detectors':10s} {'legs':7s} {'time UTC':>8}")
    for c in rows[:max_rows]:
        lines.append(f"{c['id']:>5} {c['bel']:>8.5f} {c['pl']:>8.5f} "
                     f"{_fmt_deg(c['lat_deg'], 'N', 'S'):>12} {_fmt_deg(c['lon_deg'], 'E', 'W'):>13} "
                     f"{c['sigma_m']:>5.1f}m {c['looks']:>5} {c['detections']:>4} {_STATE[c['state']]:5s} "
                     f"{','.join(c['detectors'])[:10]:10s} {','.join(map(str, c['legs']))[:7]:7s} {_hms(c['t'])}")
    if len(rows) > max_rows:
        lines.append(f"  ... and {len(rows) - max_rows} more")
    if not rows:
        lines.append("  (no contacts yet)")
    return "\n".join(line[:width] for line in lines)


def _hms(t: float) -> str:
    """UTC time of day of the evidence behind a contact (recorded time in a replay)."""
    return datetime.fromtimestamp(t, tz=timezone.utc).strftime("%H:%M:%S")


class Monitor:
    """Follow a node and keep a terminal screen (and optionally a PNG) up to date.

    Parameters
    ----------
    follower : NodeFollower
        The subscription.
    out : text stream
        Where the screen goes (a terminal; ANSI escapes are written only when ``ansi``).
    png, png_every_s, state_dir
        Belief-map PNG path, how often to rewrite it, and a node state directory whose newest
        snapshot gives the real belief map (else the map is drawn from the contacts alone).
    """

    def __init__(self, follower: NodeFollower, *, out: TextIO = sys.stdout, refresh_s: float = 0.5,
                 ansi: bool | None = None, max_rows: int | None = None, png: str | Path | None = None,
                 png_every_s: float = 5.0, state_dir: str | Path | None = None) -> None:
        self.follower, self.out, self.refresh_s = follower, out, refresh_s
        self.ansi = out.isatty() if ansi is None else ansi
        self.max_rows = max_rows
        self.png = Path(png) if png else None
        self.png_every_s, self.state_dir = png_every_s, state_dir
        self.frames = 0
        self.pngs = 0
        self.png_error = ""
        self.png_note = ""
        """Why the last PNG has no belief map under its contacts (empty: it has one, or none was asked)."""
        self._last_draw = -1e9
        self._last_png = -1e9

    def draw(self) -> str:
        size = shutil.get_terminal_size((100, 30))
        rows = self.max_rows if self.max_rows is not None else max(3, size.lines - 8)
        screen = render_screen(self.follower, now=time.monotonic(), width=size.columns, max_rows=rows)
        if self.png is not None:
            shown = f"{self.png} ({self.pngs} written)"
            if self.png_note:  # first: a long path must not cut it off
                shown = f"contacts only, no belief map yet: {shown}"
            note = f"png       {self.png_error}" if self.png_error else f"png       {shown}"
            screen += "\n" + note[:size.columns]
        if self.ansi:
            body = "".join(line + CLEAR_EOL + "\n" for line in screen.split("\n"))
            self.out.write((CLEAR_ALL if self.frames == 0 else "") + HOME + body + CLEAR_EOS)
        else:
            self.out.write(screen + "\n\n")
        self.out.flush()
        self.frames += 1
        return screen

    def write_png(self) -> Path | None:
        """Rewrite the PNG now (None when no PNG was asked for)."""
        if self.png is None:
            return None
        from .beliefmap import draw_belief_map, grid_raster, load_state_grid

        raster, self.png_note = None, ""
        if self.state_dir:
            try:
                raster = grid_raster(load_state_grid(self.state_dir))
            except AtrError as exc:  # no snapshot yet (a node just started): the contacts alone until then
                self.png_note = f"contacts only, no belief map: {exc}"
        contacts = self.follower.book.contacts(include_withdrawn=True)
        title = f"atr-node {self.follower.endpoint}: {self.follower.book.n_live} live contacts, " \
                f"{datetime.now(timezone.utc):%H:%M:%S} UTC"
        draw_belief_map(self.png, contacts, raster=raster, title=title)
        self.pngs += 1
        return self.png

    def _tick(self) -> None:
        now = time.monotonic()
        if now - self._last_draw >= self.refresh_s:
            self._last_draw = now
            self.draw()
        if self.png is not None and now - self._last_png >= self.png_every_s:
            self._last_png = now
            self._safe_png()

    def _safe_png(self) -> None:
        try:
            self.write_png()
            self.png_error = ""
        except AtrError as exc:  # e.g. no snapshot yet: keep monitoring, say why on the next frame
            self.png_error = str(exc)

    def run(self, *, duration_s: float | None = None, until_silent_s: float | None = None,
            stop: threading.Event | None = None) -> str:
        """Monitor until a stop condition (see :meth:`NodeFollower.follow`); a last frame and
        PNG are written before returning the reason."""
        try:
            why = self.follower.follow(duration_s=duration_s, until_silent_s=until_silent_s, stop=stop,
                                       tick=self._tick, tick_s=min(self.refresh_s, 0.25))
        except KeyboardInterrupt:
            why = "interrupt"
        self.draw()
        if self.png is not None:
            self._safe_png()
        return why
