"""Waiting for events in tests, never for an amount of time.

A test that talks to a node over sockets, a pty or a subprocess waits for the thing it needs
(a heartbeat, a message, a file, a count). The deadline below only stops a test that would
otherwise hang: it never decides a result on a working machine, however loaded. Set
``ATR_TEST_WAIT_S`` to give a very slow machine more (default 120 s).
"""

from __future__ import annotations

import os
import time
from typing import Callable

WAIT_S = float(os.environ.get("ATR_TEST_WAIT_S", "120"))
"""A guard against a hang only: every wait ends at its event, long before this on any machine."""


def wait_until(done: Callable[[], bool], timeout_s: float = WAIT_S, poll_s: float = 0.05,
               step: Callable[[], object] | None = None) -> bool:
    """Until ``done()`` holds (``step()`` between checks, else a sleep of ``poll_s``); False if
    it never did. The deadline is a hang guard, never a timing assertion."""
    deadline = time.monotonic() + timeout_s
    while not done():
        if time.monotonic() >= deadline:
            return False
        if step is not None:
            step()
        elif poll_s > 0:
            time.sleep(poll_s)
    return True
