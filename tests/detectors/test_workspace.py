"""The detectors' workspace: buffers reused by capacity, and malloc told to keep freed memory."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import numpy as np
import pytest

from atr_node.detectors.sat import Workspace, keep_freed_memory


def test_buffers_are_reused_while_they_fit_and_grow_when_they_do_not():
    ws = Workspace()
    a = ws.array("x", (100, 50), np.float64)
    a[:] = 1.0
    b = ws.array("x", (90, 50), np.float64)  # smaller: the same memory
    assert np.shares_memory(a, b) and b.flags.c_contiguous and b.shape == (90, 50)
    c = ws.array("x", (10, 20), np.int32)  # another dtype, same bytes
    assert np.shares_memory(a, c) and c.dtype == np.int32
    d = ws.array("x", (200, 50), np.float64)  # larger: new memory
    assert not np.shares_memory(a, d) and d.shape == (200, 50)
    ws.clear()
    assert not np.shares_memory(d, ws.array("x", (200, 50), np.float64))


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's mallopt")
def test_keep_freed_memory_applies_on_glibc_and_can_be_switched_off():
    assert keep_freed_memory() is True
    code = "from atr_node.detectors.sat import keep_freed_memory as k; print(k())"
    env = dict(os.environ, ATR_KEEP_FREED_MEMORY="0")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "False", out.stderr
