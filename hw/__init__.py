"""Link drivers of the ATR node (ICD sections 1, 2 and 4).

Every driver is a :class:`hw.base.Link` yielding :class:`atr_node.io.atrlog.LogRecord` as an
``.atrlog`` stores them, chosen by name or URL through :func:`open_link`; the table below is
imported lazily, so opening an NMEA port does not import ZeroMQ or python-can::

    name      URL forms                                          driver
    nmea      /dev/ttyS1, /dev/pts/3, socket://h:p, loop://,     hw.serial_nmea.SerialNmeaLink
              rfc2217://h:p, nmea:<any of those>
    can       can://<interface>/<channel>                        hw.can_link.CanLink
    sonar     tcp://h:p, ipc://path, inproc://name               hw.zmq_sonar.ZmqTileLink
    replay    replay:<path>, <path>.atrlog                       hw.replay.ReplayLink (+ Paced)
    stamped   stamped:<path> (time-stamped NMEA text)            hw.replay.StampedNmeaLink
    candump   candump:<path> (candump -l log)                    hw.replay.CandumpLink

Options come as keyword arguments or, pyserial-style, in the URL's query string
(``can://virtual/bench?bitrate=500000``, ``tcp://127.0.0.1:5550?socket=sub&bind=1``,
``replay:/data/m.atrlog?speed=4``); a query key a driver does not take is an error showing
the accepted ones. Recordings (``replay``, ``stamped``, ``candump``) are wrapped in
:class:`hw.replay.Paced`: option ``speed`` = a factor (default 1.0, real time) or ``max``, and
``max_gap_s`` = longest recorded silence waited out.

Decoding is apart from transport: :class:`hw.decode.NavDecoder` turns records into
navigation, :mod:`hw.nmea` and :mod:`hw.can_nav` hold the codecs (encoders included).
"""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qsl, urlsplit

from .errors import LinkClosedError, LinkError, LinkSpecError

if TYPE_CHECKING:
    from atr_node.config import LinkSettings

    from .base import Link

__all__ = ["DRIVERS", "Link", "LinkClosedError", "LinkError", "LinkSpecError", "open_link", "open_links"]

DRIVERS: dict[str, tuple[str, str]] = {
    "nmea": ("hw.serial_nmea", "SerialNmeaLink"),
    "can": ("hw.can_link", "CanLink"),
    "sonar": ("hw.zmq_sonar", "ZmqTileLink"),
    "replay": ("hw.replay", "ReplayLink"),
    "stamped": ("hw.replay", "StampedNmeaLink"),
    "candump": ("hw.replay", "CandumpLink"),
}
"""Link name -> (module, class), imported on first use."""

SCHEMES = {"socket": "nmea", "loop": "nmea", "rfc2217": "nmea", "spy": "nmea", "alt": "nmea", "hwgrep": "nmea",
           "can": "can", "tcp": "sonar", "ipc": "sonar", "inproc": "sonar", "replay": "replay",
           "stamped": "stamped", "candump": "candump"}
"""URL scheme -> link name."""

_FORM = ("expected a link name (" + ", ".join(DRIVERS) + ") with options, or a URL: /dev/ttyS1, socket://host:port, "
         "loop://, can://virtual/bench0, tcp://127.0.0.1:5550, replay:/path/mission.atrlog?speed=max")


def __getattr__(name: str) -> Any:
    if name == "Link":
        from .base import Link
        return Link
    raise AttributeError(f"module 'hw' has no attribute {name!r}")


def _coerce(value: str) -> Any:
    """Query-string value: int, float, bool (``1/0/true/false/yes/no``) or str."""
    low = value.lower()
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


def _parse(spec: str) -> tuple[str, dict[str, Any]]:
    """Link name and constructor arguments from a name or a URL."""
    if spec in DRIVERS:
        return spec, {}
    if spec.startswith("/dev/"):
        return "nmea", {"url": spec}
    if spec.startswith("nmea:"):
        return "nmea", {"url": spec[5:]}
    if spec.endswith(".atrlog") and "://" not in spec and not spec.startswith("replay:"):
        return "replay", {"path": spec}
    parts = urlsplit(spec)
    name = SCHEMES.get(parts.scheme)
    if name is None:
        raise LinkSpecError(f"link {spec!r}: unknown scheme {parts.scheme!r}; {_FORM}")
    query = {k: _coerce(v) for k, v in parse_qsl(parts.query, keep_blank_values=True)}
    if name == "nmea":  # pyserial parses its own query strings
        return name, {"url": spec}
    if name == "can":
        if not parts.netloc or not parts.path.strip("/"):
            raise LinkSpecError(f"link {spec!r}: expected can://<interface>/<channel>, e.g. can://socketcan/can0")
        return name, {"interface": parts.netloc, "channel": parts.path.strip("/"), **query}
    if name == "sonar":
        return name, {"endpoint": spec.split("?", 1)[0], **query}
    path = spec.split(":", 1)[1].split("?", 1)[0]
    if path.startswith("//"):
        path = path[2:]
    return name, {"path": path, **query}


def open_link(spec: str, **options: Any) -> "Link":
    """Open a link by name (``"nmea"``, ``"can"``, ...) or URL; see the module docstring.

    Raises
    ------
    LinkSpecError
        Unknown name or scheme, or an option the driver does not take (the message lists them).
    LinkError
        The driver could not open its port, bus or socket.
    """
    if not isinstance(spec, str) or not spec:
        raise LinkSpecError(f"link {spec!r}: {_FORM}")
    name, args = _parse(spec)
    args.update(options)
    paced = name in ("replay", "stamped", "candump")
    speed = args.pop("speed", 1.0) if paced else None
    max_gap_s = args.pop("max_gap_s", None) if paced else None
    module, cls_name = DRIVERS[name]
    cls = getattr(importlib.import_module(module), cls_name)
    params = inspect.signature(cls).parameters
    if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        unknown = sorted(set(args) - set(params))
        if unknown:
            accepted = sorted(set(params) | ({"speed", "max_gap_s"} if paced else set()))
            raise LinkSpecError(f"link {spec!r}: unknown option(s) {unknown}; {name} takes {accepted}")
    missing = [p.name for p in params.values() if p.default is p.empty and p.kind is p.POSITIONAL_OR_KEYWORD
               and p.name not in args]
    if missing:
        raise LinkSpecError(f"link {spec!r}: missing {missing}; {name} is {cls_name}{inspect.signature(cls)}")
    link = cls(**args)
    if paced:
        from .replay import Paced
        if speed in ("max", "inf", None) or speed == float("inf"):
            speed = None
        try:
            return Paced(link, None if speed is None else float(speed), max_gap_s=max_gap_s)
        except (TypeError, ValueError, LinkSpecError):
            link.shutdown()
            raise LinkSpecError(f"link {spec!r}: speed {speed!r}, max_gap_s {max_gap_s!r}: expected a speed "
                                f"factor > 0 or 'max', and max_gap_s >= 0") from None
    return link


def open_links(settings: "LinkSettings", *, curve: Any = None) -> dict[str, "Link"]:
    """Open the live links configured in ``[links]`` (empty URL or interface = not used).

    Returns ``{"sonar": ..., "nmea": ..., "can": ...}`` for the links configured; on failure
    the links already opened are shut down before the error propagates. ``curve``: an
    :class:`atr_node.security.CurveConfig` for the tile socket (None = plain).
    """
    specs: dict[str, tuple[str, dict[str, Any]]] = {}
    if settings.sonar_endpoint:
        specs["sonar"] = ("sonar", {"endpoint": settings.sonar_endpoint, "socket": settings.sonar_socket})
        if curve is not None:
            specs["sonar"][1]["curve"] = curve
    if settings.nmea_url:
        specs["nmea"] = ("nmea", {"url": settings.nmea_url, "baudrate": settings.nmea_baudrate,
                                  "reconnect": settings.nmea_reconnect})
    if settings.can_interface:
        specs["can"] = ("can", {"interface": settings.can_interface, "channel": settings.can_channel})
    opened: dict[str, Link] = {}
    try:
        for key, (name, args) in specs.items():
            opened[key] = open_link(name, **args)
    except BaseException:
        for link in opened.values():
            link.shutdown()
        raise
    return opened


def dbc_path(settings: "LinkSettings", *, base_dir: str | Path = ".") -> Path:
    """The DBC file of ``[links] can_dbc``, relative to ``base_dir`` (the config's folder) when not absolute."""
    p = Path(settings.can_dbc)
    if not p.is_absolute():
        p = Path(base_dir) / p
    return p
