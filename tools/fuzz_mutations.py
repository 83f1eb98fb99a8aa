"""Mutations for tools/fuzz_parsers.py: byte-level and structured, from a seeded generator."""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np

INTERESTING: list[Any] = [
    None, True, False, 0, -1, 1, 2, 255, 65535, 2**31 - 1, -2**31, 2**63 - 1, -2**63, 2**64 - 1,
    0.0, -0.0, 1e-320, 5e-324, 1e308, -1e308, 1e20, float("nan"), float("inf"), float("-inf"),
    "", "x", "\x00", "é\u202e", "../../../../tmp/atr-fuzz-escape", "/etc/passwd", "A" * 5000,
    b"", b"\x00" * 3, b"\xff" * 17, [], [1], [1, 2], [0, 0], [-1, 5], [2**31, 2**31], [1, 2, 3], {}, {"a": 1},
]
INTERESTING_BYTES = [0x00, 0x01, 0x7F, 0x80, 0xC0, 0xC1, 0xCA, 0xCB, 0xD9, 0xDA, 0xDB, 0xDC, 0xDE, 0xDF, 0xFF]


def mutate_bytes(rng: np.random.Generator, data: bytes, others: list[bytes]) -> bytes:
    """1 to 4 byte-level mutations of ``data``."""
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 5))):
        op = int(rng.integers(0, 8))
        n = len(b)
        if op == 0 and n:  # bit flips
            for _ in range(int(rng.integers(1, 9))):
                i = int(rng.integers(0, n))
                b[i] ^= 1 << int(rng.integers(0, 8))
        elif op == 1 and n:  # interesting byte
            b[int(rng.integers(0, n))] = INTERESTING_BYTES[int(rng.integers(0, len(INTERESTING_BYTES)))]
        elif op == 2 and n:  # truncation
            del b[int(rng.integers(0, n)):]
        elif op == 3:  # insertion of random bytes
            i = int(rng.integers(0, n + 1))
            b[i:i] = rng.integers(0, 256, int(rng.integers(1, 32)), dtype=np.uint8).tobytes()
        elif op == 4 and n:  # deletion of a chunk
            i = int(rng.integers(0, n))
            del b[i:i + int(rng.integers(1, 64))]
        elif op == 5 and n:  # duplicated chunk
            i = int(rng.integers(0, n))
            chunk = b[i:i + int(rng.integers(1, 256))]
            j = int(rng.integers(0, n + 1))
            b[j:j] = chunk
        elif op == 6 and others:  # splice with another seed
            o = others[int(rng.integers(0, len(others)))]
            i, j = int(rng.integers(0, n + 1)), int(rng.integers(0, len(o) + 1))
            b = b[:i] + bytearray(o[j:])
        elif op == 7 and n >= 4:  # overwrite 4 bytes with an extreme integer
            i = int(rng.integers(0, n - 3))
            b[i:i + 4] = int(rng.choice([0, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000])).to_bytes(4, "big")
    return bytes(b)


def _slots(obj: Any, out: list[tuple[Any, Any]]) -> list[tuple[Any, Any]]:
    """Every (container, key) of a nested structure of dicts and lists."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            out.append((obj, k))
            _slots(v, out)
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out.append((obj, i))
            _slots(v, out)
    return out


def _extreme(rng: np.random.Generator, v: Any) -> Any:
    """A value of the same type as ``v`` but extreme."""
    if isinstance(v, bool):
        return not v
    if isinstance(v, int):
        return int(rng.choice([0, -1, v + 1, v - 1, 2**31, 2**63 - 1, -2**63, v * 1000]))
    if isinstance(v, float):
        return float(rng.choice([0.0, -v, v * 1e300, v * 1e-300, 1e308, -1e308, 5e-324, math.nan, math.inf]))
    if isinstance(v, str):
        return str(rng.choice(["", v * 50, v + "\x00", "../" * 8 + v, v.upper(), "\ud7ff" + v]))
    if isinstance(v, (bytes, bytearray)):
        n = len(v)
        k = int(rng.integers(0, 4))
        if k == 0:
            return bytes(v[: int(rng.integers(0, n + 1))])
        if k == 1:
            return bytes(v) + bytes(int(rng.integers(1, 64)))
        if k == 2 and n:
            b = bytearray(v)
            b[int(rng.integers(0, n))] ^= 0xFF
            return bytes(b)
        return np.full(max(n // 8, 1), rng.choice([np.nan, np.inf, -np.inf, -1.0, 1e300]), "<f8").tobytes()[:n] or b"\x00"
    if isinstance(v, list):
        return v[:-1] if v and rng.random() < 0.5 else v + v
    return None


def mutate_struct(rng: np.random.Generator, obj: Any) -> Any:
    """1 to 3 structural mutations of a deep copy of ``obj`` (dicts, lists, scalars)."""
    out = copy.deepcopy(obj)
    for _ in range(int(rng.integers(1, 4))):
        slots = _slots(out, [])
        if not slots:
            return INTERESTING[int(rng.integers(0, len(INTERESTING)))]
        parent, key = slots[int(rng.integers(0, len(slots)))]
        op = int(rng.integers(0, 6))
        if op == 0 and isinstance(parent, dict):
            del parent[key]
        elif op == 1:
            parent[key] = copy.deepcopy(INTERESTING[int(rng.integers(0, len(INTERESTING)))])
        elif op == 2:
            parent[key] = _extreme(rng, parent[key])
        elif op == 3 and isinstance(parent, dict):
            parent[str(rng.choice(["extra", "v2", "\x00", "data2", key if isinstance(key, str) else "k"])) + "_"] = 1
        elif op == 4:  # type swap
            v = parent[key]
            parent[key] = str(v)[:100] if not isinstance(v, str) else [v]
        else:
            parent[key] = _extreme(rng, parent[key])
    return out


def _sanitize(obj: Any) -> Any:
    """Make a mutated structure packable by msgpack (ints out of 64-bit range become floats)."""
    if isinstance(obj, dict):
        return {(_sanitize(k) if isinstance(k, (str, int, bytes)) else str(k)): _sanitize(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_sanitize(v) for v in obj]
    if isinstance(obj, int) and not isinstance(obj, bool) and not -2**63 <= obj < 2**64:
        return float(obj)
    return obj
