"""ZeroMQ endpoints given on the command line or in [links], checked before any socket is
made, so that a typo fails in one line naming the option instead of a ZeroMQ traceback, and a
port out of range is refused rather than bound somewhere else (libzmq takes
``tcp://127.0.0.1:99999`` modulo 65536).

Accepted forms (the transports the node and its tools use)::

    tcp://HOST:PORT      HOST a name, an address, [IPv6], an interface or * (bind: any);
                         PORT 1-65535, or * (bind: a free port)
    ipc://PATH           a Unix-domain socket path
    inproc://NAME        a name inside one process (tests)
"""

from __future__ import annotations

from ..errors import AtrError

SCHEMES = ("tcp", "ipc", "inproc")
EXPECTED = "expected tcp://HOST:PORT (PORT 1-65535), ipc://PATH or inproc://NAME, e.g. tcp://127.0.0.1:5560"


def endpoint_problem(endpoint: str) -> str | None:
    """Why ``endpoint`` is not a usable ZeroMQ endpoint, or None when it is."""
    scheme, sep, rest = endpoint.partition("://")
    if not sep:
        return "no transport (tcp://, ipc:// or inproc://)"
    if scheme not in SCHEMES:
        return f"unknown transport {scheme + '://'!r}"
    if not rest:
        return f"nothing after {scheme}://"
    if scheme != "tcp":
        return None
    # a connect may name its source first: tcp://SOURCE:PORT;HOST:PORT (zmq_tcp(7))
    address = rest.rpartition(";")[2]
    host, colon, port = address.rpartition(":")
    if not colon or not host:
        return "no port (tcp://HOST:PORT)" if not colon else "no host before the port"
    if host.startswith("[") != host.endswith("]"):
        return f"unbalanced brackets in host {host!r}"
    if port == "*":
        return None
    if not port.isdigit():
        return f"port {port!r} is not a number"
    if not 1 <= int(port) <= 65535:
        return f"port {port} out of range 1-65535"
    return None


def check_endpoint(endpoint: str, where: str) -> str:
    """Return ``endpoint`` when usable, else raise :class:`AtrError` naming ``where`` (the
    option or setting it came from: ``--publish``, ``links.publish_endpoint``)."""
    problem = endpoint_problem(endpoint)
    if problem is not None:
        raise AtrError(f"{where} {endpoint!r}: {problem}; {EXPECTED}")
    return endpoint


def check_optional_endpoint(endpoint: str | None, where: str) -> str | None:
    """:func:`check_endpoint` for an option that may be absent or switched off (None, ``""``
    or ``none``, returned unchanged)."""
    if endpoint is None or endpoint in ("", "none"):
        return endpoint
    return check_endpoint(endpoint, where)


LINK_ENDPOINTS = ("sonar_endpoint", "publish_endpoint", "snapshot_endpoint")
"""The ZeroMQ endpoints of ``[links]`` a node binds or connects (empty = not used)."""


def check_link_endpoints(settings) -> None:
    """Check every ZeroMQ endpoint of ``settings.links`` (``atr-node run``), naming the key."""
    for key in LINK_ENDPOINTS:
        value = getattr(settings.links, key, "")
        check_optional_endpoint(value, f"links.{key} (file {settings.source})" if settings.source else f"links.{key}")
