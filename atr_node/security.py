"""ZeroMQ CURVE authentication of the node's sockets, with keys from files.

Off by default (loopback on the bench); on the vehicle network, set in ``[links]``:

- ``curve_secret_key_file``: the node's key pair, a ZeroMQ certificate file holding
  ``public-key`` and ``secret-key`` (Z85). It must not be readable by group or others.
- ``curve_authorized_dir``: a folder of public-key certificates (``*.key``) of the peers
  allowed to connect to the node's server sockets (the contact PUB socket, and the tile socket
  when it binds); empty = any peer that knows the node's public key.
- ``sonar_server_key_file``: the sonar processor's public key, when the node's tile socket
  connects to it (the node is then the CURVE client).

With CURVE on, every byte on the two sockets is encrypted and authenticated (CurveZMQ:
Curve25519 key exchange, XSalsa20-Poly1305 messages); a peer without the right keys never
completes the handshake and sees no message. Peers are checked by a ZAP handler
(``zmq.auth.thread.ThreadAuthenticator``, one per ZeroMQ context) against the authorized set.

Key files are made with :func:`generate_keypair` (or ``zmq.auth.create_certificates``): it
writes ``<name>.key`` (public, to hand out) and ``<name>.key_secret`` (mode 0600).
"""

from __future__ import annotations

import atexit
import itertools
import os
import stat
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import zmq
import zmq.auth
import zmq.utils.z85
from zmq.auth.thread import ThreadAuthenticator

from .errors import ConfigError

if TYPE_CHECKING:
    from .config import Settings

PUBLIC_SUFFIX = ".key"
SECRET_SUFFIX = ".key_secret"
Z85_KEY_CHARS = 40
"""A Curve25519 key is 32 bytes, 40 characters of Z85."""


@dataclass(frozen=True)
class CurveKeyPair:
    """A Curve25519 key pair, both keys Z85-encoded (40 ASCII bytes)."""

    public_key: bytes
    secret_key: bytes

    def __post_init__(self) -> None:
        for name in ("public_key", "secret_key"):
            _check_z85(getattr(self, name), name, "<memory>")
        if zmq.curve_public(self.secret_key) != self.public_key:
            raise ConfigError("the public key does not belong to the secret key", key="curve key pair")


def _check_z85(key: object, what: str, path: str) -> bytes:
    if not isinstance(key, bytes) or len(key) != Z85_KEY_CHARS:
        raise ConfigError(f"{what}: expected {Z85_KEY_CHARS} Z85 characters, got {key!r:.60}", path=path)
    try:
        raw = zmq.utils.z85.decode(key)
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise ConfigError(f"{what}: not Z85 ({exc})", path=path) from None
    if len(raw) != 32:
        raise ConfigError(f"{what}: decodes to {len(raw)} bytes, expected 32", path=path)
    return key


def _read_cert(path: str | os.PathLike[str]) -> tuple[bytes | None, bytes | None]:
    """(public, secret) keys of a ZeroMQ certificate file, each None when absent."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise ConfigError("key file not found", path=str(p)) from None
    except OSError as exc:
        raise ConfigError(f"key file unreadable: {exc.strerror}", path=str(p)) from None
    if len(data) > 64 << 10:
        raise ConfigError(f"{len(data)} bytes is not a key file (expected a ZeroMQ certificate)", path=str(p))
    public = secret = None
    for line in data.splitlines():
        line = line.strip()
        if line.startswith(b"public-key"):
            public = line.split(b"=", 1)[-1].strip(b" \t'\"")
        elif line.startswith(b"secret-key"):
            secret = line.split(b"=", 1)[-1].strip(b" \t'\"")
    return public, secret


def load_public_key(path: str | os.PathLike[str]) -> bytes:
    """The Z85 public key of a certificate file (``*.key`` or ``*.key_secret``).

    Raises
    ------
    ConfigError
        Missing file, no ``public-key`` line, or a key that is not 40 Z85 characters.
    """
    public, _ = _read_cert(path)
    if public is None:
        raise ConfigError("no 'public-key = \"...\"' line (expected a ZeroMQ certificate)", path=str(path))
    return _check_z85(public, "public-key", str(path))


def load_keypair(path: str | os.PathLike[str], *, check_mode: bool = True) -> CurveKeyPair:
    """The key pair of a secret certificate file (``*.key_secret``).

    Raises
    ------
    ConfigError
        Missing file or keys, malformed keys, keys that do not match, or (``check_mode``) a
        file that group or others may read: a secret key must stay secret.
    """
    p = Path(path)
    public, secret = _read_cert(p)
    if secret is None:
        raise ConfigError("no 'secret-key = \"...\"' line: this is a public key file, the node needs its "
                          f"secret one (*{SECRET_SUFFIX})", path=str(p))
    if check_mode and p.stat().st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(f"mode {stat.filemode(p.stat().st_mode)}: a secret key file must not be readable by "
                          f"group or others (chmod 600 {p})", path=str(p))
    secret = _check_z85(secret, "secret-key", str(p))
    derived = zmq.curve_public(secret)
    if public is not None and _check_z85(public, "public-key", str(p)) != derived:
        raise ConfigError("public-key does not belong to secret-key", path=str(p))
    return CurveKeyPair(public_key=derived, secret_key=secret)


def load_authorized_keys(directory: str | os.PathLike[str]) -> frozenset[bytes]:
    """Public keys of every ``*.key`` certificate in ``directory`` (the peers allowed in)."""
    d = Path(directory)
    if not d.is_dir():
        raise ConfigError("authorized keys folder not found", path=str(d))
    keys = frozenset(load_public_key(f) for f in sorted(d.glob(f"*{PUBLIC_SUFFIX}")))
    if not keys:
        raise ConfigError(f"no *{PUBLIC_SUFFIX} public key in the authorized keys folder: nobody could connect",
                          path=str(d))
    return keys


def generate_keypair(directory: str | os.PathLike[str], name: str) -> tuple[Path, Path]:
    """Write a new key pair ``<name>.key`` (public) and ``<name>.key_secret`` (mode 0600).

    Returns
    -------
    (public_path, secret_path)
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    public, secret = zmq.auth.create_certificates(d, name)
    os.chmod(secret, 0o600)
    return Path(public), Path(secret)


# -- ZAP: who may connect -------------------------------------------------------------------------

class _Allowed:
    """ZAP credentials provider: a set of Z85 public keys, or None for anyone."""

    def __init__(self, keys: frozenset[bytes] | None) -> None:
        self.keys = keys

    def callback(self, domain: str, key: bytes) -> bool:
        return self.keys is None or key in self.keys


_auth_lock = threading.Lock()
_authenticators: dict[int, ThreadAuthenticator] = {}
_domains = itertools.count(1)


def _authenticator(ctx: zmq.Context) -> ThreadAuthenticator:
    with _auth_lock:
        auth = _authenticators.get(id(ctx))
        if auth is None:
            auth = ThreadAuthenticator(ctx)
            auth.start()
            _authenticators[id(ctx)] = auth
        return auth


@atexit.register
def stop_authenticators() -> None:
    """Stop the ZAP threads (at exit; tests may call it to clean up)."""
    with _auth_lock:
        for auth in _authenticators.values():
            try:
                auth.stop()
            except zmq.ZMQError:
                pass
        _authenticators.clear()


@dataclass(frozen=True)
class CurveConfig:
    """CURVE settings of one node: its key pair, who may connect, the sonar server's key."""

    keys: CurveKeyPair
    authorized: frozenset[bytes] | None = None
    """Z85 public keys allowed to connect to the node's server sockets; None = anyone with the node's public key."""
    server_public_key: bytes | None = None
    """Public key of the server this node connects to (the sonar processor), for client sockets."""

    def secure_server(self, sock: zmq.Socket) -> None:
        """Make ``sock`` (before bind/connect) a CURVE server that admits the authorized peers."""
        domain = f"atr-node-{next(_domains)}"
        _authenticator(sock.context).configure_curve_callback(domain, _Allowed(self.authorized))
        sock.zap_domain = domain.encode()
        sock.curve_secretkey = self.keys.secret_key
        sock.curve_publickey = self.keys.public_key
        sock.curve_server = True

    def secure_client(self, sock: zmq.Socket, server_public_key: bytes | None = None) -> None:
        """Make ``sock`` (before connect) a CURVE client of the server with the given public key."""
        server = server_public_key or self.server_public_key
        if server is None:
            raise ConfigError("a CURVE client socket needs the server's public key", key="links.sonar_server_key_file")
        sock.curve_secretkey = self.keys.secret_key
        sock.curve_publickey = self.keys.public_key
        sock.curve_serverkey = server


def curve_from_settings(settings: "Settings") -> CurveConfig | None:
    """The CURVE settings of ``[links]`` (None: CURVE off); relative paths are taken from the
    config file's folder."""
    from .config import resolve_relative

    links = settings.links
    if not links.curve_secret_key_file:
        for key in ("curve_authorized_dir", "sonar_server_key_file"):
            if getattr(links, key):
                raise ConfigError("set only with links.curve_secret_key_file (CURVE is off without it)",
                                  path=settings.source, key=f"links.{key}")
        return None
    keys = load_keypair(resolve_relative(settings, links.curve_secret_key_file))
    authorized = (load_authorized_keys(resolve_relative(settings, links.curve_authorized_dir))
                  if links.curve_authorized_dir else None)
    server = load_public_key(resolve_relative(settings, links.sonar_server_key_file)) if links.sonar_server_key_file else None
    return CurveConfig(keys=keys, authorized=authorized, server_public_key=server)
