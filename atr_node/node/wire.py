"""The outputs to the autonomy layer (ICD section 3), frame by frame.

ZeroMQ PUB socket; every message is two frames::

    frame 0: topic, ASCII: b"contact" or b"heartbeat"
    frame 1: msgpack map (``packb(..., use_bin_type=True)``):

    contact   {type "contact", v 1, id int, state "new"|"update"|"withdrawn", t float,
               lat_deg, lon_deg, east_m, north_m, sigma_m, bel, pl, m_theta: float,
               looks int, detections int, detectors [str], legs [int]
               (v1.1, optional, all three or none: an extended object, a wreck)
               length_m, width_m: float >= 0, heading_deg: float in [0, 180),
               (v1.1) seq int >= 1: per node, +1 for every contact message published}
    heartbeat {type "heartbeat", v 1, t, uptime_s: float, tiles_in, tiles_done,
               tiles_dropped, tiles_rejected, queue_depth: int,
               latency_ms {p50, p99: float}, mode "nominal"|"degraded"}

(v1.1) The snapshot endpoint for late joiners (ROUTER on the node, REQ or DEALER in the client)::

    request   one frame: b"contacts"
    reply     one frame, msgpack map: {seq int: the last seq published (0: none yet),
                                       contacts [contact map of every live contact]}
              or, to any other request: {error str}

A v1.1 publisher sets ``seq`` on every contact; readers still take v1 messages without it
(``validate_contact(m)``; ``require_seq=True`` checks a v1.1 publisher's output).

This module is the only place that knows the layout: the node builds messages with
:func:`contact_message` / :func:`heartbeat_message`, subscribers and tests check them with
:func:`validate_contact` / :func:`validate_heartbeat`; :func:`snapshot_reply` /
:func:`read_snapshot_reply` are the two ends of the snapshot endpoint.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import msgpack

WIRE_VERSION = 1
TOPIC_CONTACT = b"contact"
TOPIC_HEARTBEAT = b"heartbeat"

CONTACT_FIELDS: dict[str, type | tuple[type, ...]] = {
    "type": str, "v": int, "id": int, "state": str, "t": float, "lat_deg": float, "lon_deg": float,
    "east_m": float, "north_m": float, "sigma_m": float, "bel": float, "pl": float, "m_theta": float,
    "looks": int, "detections": int, "detectors": list, "legs": list,
}
CONTACT_OPTIONAL_FIELDS: dict[str, type | tuple[type, ...]] = {
    "length_m": float, "width_m": float, "heading_deg": float,
}
"""(ICD v1.1 section 3) The extent of an extended object: present together, or absent."""
CONTACT_SEQ_FIELDS: dict[str, type | tuple[type, ...]] = {"seq": int}
"""(ICD v1.1 section 3) The publisher's message counter: on every message of a v1.1 node,
absent from v1 messages (which readers still take)."""
SNAPSHOT_REQUEST = b"contacts"
"""(ICD v1.1 section 3) The one request the snapshot endpoint answers."""
HEARTBEAT_FIELDS: dict[str, type | tuple[type, ...]] = {
    "type": str, "v": int, "t": float, "uptime_s": float, "tiles_in": int, "tiles_done": int,
    "tiles_dropped": int, "tiles_rejected": int, "queue_depth": int, "latency_ms": dict, "mode": str,
}
CONTACT_STATES = ("new", "update", "withdrawn")
MODES = ("nominal", "degraded")


def contact_message(*, id: int, state: str, t: float, lat_deg: float, lon_deg: float, east_m: float,
                    north_m: float, sigma_m: float, bel: float, pl: float, m_theta: float, looks: int,
                    detections: int, detectors: Sequence[str], legs: Sequence[int], length_m: float | None = None,
                    width_m: float | None = None, heading_deg: float | None = None,
                    seq: int | None = None) -> dict[str, Any]:
    """The ICD ``contact`` map, with every field of its declared type (the extent and the
    v1.1 ``seq`` only when given)."""
    m = {"type": "contact", "v": WIRE_VERSION, "id": int(id), "state": str(state), "t": float(t),
         "lat_deg": float(lat_deg), "lon_deg": float(lon_deg), "east_m": float(east_m),
         "north_m": float(north_m), "sigma_m": float(sigma_m), "bel": float(bel), "pl": float(pl),
         "m_theta": float(m_theta), "looks": int(looks), "detections": int(detections),
         "detectors": [str(d) for d in detectors], "legs": [int(x) for x in legs]}
    for k, v in (("length_m", length_m), ("width_m", width_m), ("heading_deg", heading_deg)):
        if v is not None:
            m[k] = float(v)
    if seq is not None:
        m["seq"] = int(seq)
    problems = validate_contact(m)
    if problems:
        raise ValueError(f"contact {id}: {'; '.join(problems)}")
    return m


def heartbeat_message(*, t: float, uptime_s: float, tiles_in: int, tiles_done: int, tiles_dropped: int,
                      tiles_rejected: int, queue_depth: int, p50_ms: float, p99_ms: float,
                      mode: str) -> dict[str, Any]:
    """The ICD ``heartbeat`` map."""
    return {"type": "heartbeat", "v": WIRE_VERSION, "t": float(t), "uptime_s": float(uptime_s),
            "tiles_in": int(tiles_in), "tiles_done": int(tiles_done), "tiles_dropped": int(tiles_dropped),
            "tiles_rejected": int(tiles_rejected), "queue_depth": int(queue_depth),
            "latency_ms": {"p50": float(p50_ms), "p99": float(p99_ms)}, "mode": str(mode)}


def _check_fields(m: Any, fields: Mapping[str, Any], kind: str,
                  optional: Mapping[str, Any] | None = None) -> list[str]:
    if not isinstance(m, Mapping):
        return [f"expected a map, got {type(m).__name__}"]
    problems = []
    optional = optional or {}
    for k, tp in {**fields, **optional}.items():
        if k not in m:
            if k not in optional:
                problems.append(f"missing '{k}'")
            continue
        v = m[k]
        if tp is float:
            ok = isinstance(v, float)
        elif tp is int:
            ok = isinstance(v, int) and not isinstance(v, bool)
        else:
            ok = isinstance(v, tp)
        if not ok:
            problems.append(f"'{k}' should be {getattr(tp, '__name__', tp)}, got {type(v).__name__}")
    extra = set(m) - set(fields) - set(optional)
    if extra:
        problems.append(f"unexpected keys {sorted(extra)}")
    if not problems:
        if m["type"] != kind:
            problems.append(f"type should be '{kind}'")
        if m["v"] != WIRE_VERSION:
            problems.append(f"v should be {WIRE_VERSION}")
    return problems


def validate_contact(m: Any, *, require_seq: bool = False) -> list[str]:
    """Problems that keep ``m`` from being an ICD contact (empty when it is one).

    A v1 message (no ``seq``) passes unless ``require_seq`` (what a v1.1 publisher sends);
    a ``seq`` that is there must be an int >= 1.
    """
    problems = _check_fields(m, CONTACT_FIELDS, "contact", {**CONTACT_OPTIONAL_FIELDS, **CONTACT_SEQ_FIELDS})
    if problems:
        return problems
    if "seq" in m:
        if m["seq"] < 1:
            problems.append(f"'seq' should be >= 1, got {m['seq']}")
    elif require_seq:
        problems.append("missing 'seq' (ICD v1.1: every contact message of a v1.1 node carries it)")
    extent = [k for k in CONTACT_OPTIONAL_FIELDS if k in m]
    if extent:
        if len(extent) != len(CONTACT_OPTIONAL_FIELDS):
            problems.append(f"extent needs all of {list(CONTACT_OPTIONAL_FIELDS)}, got only {extent}")
        elif not all(math.isfinite(m[k]) for k in extent):
            problems.append("extent (length_m, width_m, heading_deg) is not finite")
        elif not (0.0 <= m["width_m"] <= m["length_m"] and 0.0 <= m["heading_deg"] < 180.0):
            problems.append(f"need 0 <= width_m <= length_m and heading_deg in [0, 180), got length_m="
                            f"{m['length_m']} width_m={m['width_m']} heading_deg={m['heading_deg']}")
    if m["state"] not in CONTACT_STATES:
        problems.append(f"state {m['state']!r} not in {CONTACT_STATES}")
    for k in ("lat_deg", "lon_deg", "east_m", "north_m", "sigma_m", "bel", "pl", "m_theta", "t"):
        if not math.isfinite(m[k]):
            problems.append(f"'{k}' is not finite")
    if not problems:
        if not (-90 <= m["lat_deg"] <= 90 and -180 <= m["lon_deg"] <= 180):
            problems.append("position outside WGS84 range")
        if not (0.0 <= m["bel"] <= m["pl"] <= 1.0 + 1e-12):
            problems.append(f"need 0 <= bel <= pl <= 1, got bel={m['bel']} pl={m['pl']}")
        if abs(m["bel"] + (1.0 - m["pl"]) + m["m_theta"] - 1.0) > 1e-9:
            problems.append("bel + (1 - pl) + m_theta != 1")
        if m["sigma_m"] < 0 or m["looks"] < 0 or m["detections"] < 0:
            problems.append("negative sigma_m, looks or detections")
        if not all(isinstance(d, str) for d in m["detectors"]):
            problems.append("detectors must be strings")
        if not all(isinstance(x, int) and not isinstance(x, bool) for x in m["legs"]):
            problems.append("legs must be integers")
    return problems


def validate_heartbeat(m: Any) -> list[str]:
    """Problems that keep ``m`` from being an ICD v1 heartbeat (empty when it is one)."""
    problems = _check_fields(m, HEARTBEAT_FIELDS, "heartbeat")
    if problems:
        return problems
    lat = m["latency_ms"]
    if set(lat) != {"p50", "p99"} or not all(isinstance(lat[k], float) for k in ("p50", "p99")):
        problems.append("latency_ms must be {p50: float, p99: float}")
    if m["mode"] not in MODES:
        problems.append(f"mode {m['mode']!r} not in {MODES}")
    for k in ("tiles_in", "tiles_done", "tiles_dropped", "tiles_rejected", "queue_depth"):
        if m[k] < 0:
            problems.append(f"'{k}' is negative")
    return problems


def snapshot_reply(seq: int, contacts: Sequence[Mapping[str, Any]]) -> bytes:
    """The snapshot endpoint's answer to :data:`SNAPSHOT_REQUEST` (one frame)."""
    return msgpack.packb({"seq": int(seq), "contacts": [dict(c) for c in contacts]}, use_bin_type=True)


def snapshot_error(why: str) -> bytes:
    """The snapshot endpoint's answer to anything else (one frame)."""
    return msgpack.packb({"error": str(why)}, use_bin_type=True)


def read_snapshot_reply(frame: bytes) -> tuple[int, list[dict[str, Any]]]:
    """(seq, contacts) of a snapshot reply.

    Raises
    ------
    ValueError
        Not msgpack, an ``error`` reply (its text), or not ``{seq: int >= 0, contacts: [map]}``
        (the contacts themselves are checked by the caller, one by one).
    """
    try:
        m = msgpack.unpackb(frame, raw=False)
    except (ValueError, msgpack.UnpackException) as exc:
        raise ValueError(f"snapshot reply is not msgpack ({exc})") from None
    if isinstance(m, Mapping) and "error" in m:
        raise ValueError(f"the node refused the snapshot request: {m['error']}")
    if not (isinstance(m, Mapping) and set(m) == {"seq", "contacts"} and isinstance(m["seq"], int)
            and not isinstance(m["seq"], bool) and m["seq"] >= 0 and isinstance(m["contacts"], list)
            and all(isinstance(c, Mapping) for c in m["contacts"])):
        raise ValueError("snapshot reply should be a map {seq: int >= 0, contacts: [contact map]}")
    return m["seq"], [dict(c) for c in m["contacts"]]


def encode(topic: bytes, message: Mapping[str, Any]) -> list[bytes]:
    """The two frames of a message."""
    return [topic, msgpack.packb(dict(message), use_bin_type=True)]


def decode(frames: Sequence[bytes]) -> tuple[str, dict[str, Any]]:
    """(topic, map) of two received frames."""
    if len(frames) != 2:
        raise ValueError(f"expected 2 frames (topic, msgpack map), got {len(frames)}")
    return frames[0].decode("ascii"), msgpack.unpackb(frames[1], raw=False)
