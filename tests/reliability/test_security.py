"""Security (issue 10): ZeroMQ CURVE with keys from files on the PUB and tile sockets, real
sockets on loopback; the systemd unit's sandbox."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import msgpack
import pytest
import zmq

from atr_node.calibration.model import PerformanceModel
from atr_node.config import load_settings
from atr_node.errors import ConfigError
from atr_node.node.publisher import Subscriber
from atr_node.node.service import NodeService
from atr_node.security import CurveConfig, generate_keypair, load_authorized_keys, load_keypair, load_public_key
from hw.errors import LinkSpecError
from hw.zmq_sonar import ZmqTileLink

from ..waiting import WAIT_S, wait_until

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def keys(tmp_path):
    """Key pairs of the node, an authorized peer and an intruder; the peer alone is authorized."""
    out = {}
    for name in ("node", "peer", "intruder"):
        out[name] = generate_keypair(tmp_path / "keys", name)
    auth = tmp_path / "authorized"
    auth.mkdir()
    shutil.copy(out["peer"][0], auth / "peer.key")
    return tmp_path, out, auth


def test_key_files_round_trip_and_secret_mode_is_enforced(keys):
    _, k, auth = keys
    pair = load_keypair(k["node"][1])
    assert pair.public_key == load_public_key(k["node"][0]) == zmq.curve_public(pair.secret_key)
    assert oct(k["node"][1].stat().st_mode & 0o777) == "0o600"
    assert load_authorized_keys(auth) == {load_public_key(k["peer"][0])}
    os.chmod(k["node"][1], 0o644)
    with pytest.raises(ConfigError, match="readable by group or others"):
        load_keypair(k["node"][1])


@pytest.mark.parametrize("text, fragment", [
    (b"", "no 'secret-key"),
    (b'public-key = "abc"\nsecret-key = "def"\n', "expected 40 Z85 characters"),
    (b'secret-key = "' + b"~" * 40 + b'"\n', "not Z85"),
    (b"\x00\xff" * 40000, "is not a key file"),
])
def test_malformed_key_files_are_clear_errors(tmp_path, text, fragment):
    p = tmp_path / "bad.key_secret"
    p.write_bytes(text)
    os.chmod(p, 0o600)
    with pytest.raises(ConfigError, match=fragment) as err:
        load_keypair(p)
    assert str(p) in str(err.value)


def test_public_key_file_given_as_secret_and_mismatched_pair(keys):
    _, k, _ = keys
    with pytest.raises(ConfigError, match="public key file"):
        load_keypair(k["node"][0], check_mode=False)
    mixed = k["node"][1].parent / "mixed.key_secret"
    pub = k["peer"][0].read_text().split("public-key", 1)[1].splitlines()[0]
    sec = k["node"][1].read_text().split("secret-key", 1)[1].splitlines()[0]
    mixed.write_text(f"curve\n    public-key{pub}\n    secret-key{sec}\n")
    os.chmod(mixed, 0o600)
    with pytest.raises(ConfigError, match="does not belong"):
        load_keypair(mixed)


def _settings(tmp_path, k, auth, **extra):
    cfg = tmp_path / "node.toml"
    lines = ["[links]", f'curve_secret_key_file = "{k["node"][1]}"', f'curve_authorized_dir = "{auth}"']
    lines += [f'{key} = "{v}"' for key, v in extra.items()]
    cfg.write_text("\n".join(lines) + "\n")
    return load_settings(cfg)


def _client(k, name) -> CurveConfig:
    return CurveConfig(keys=load_keypair(k[name][1]), server_public_key=load_public_key(k["node"][0]))


def test_node_pub_socket_admits_only_authorized_curve_subscribers(keys):
    tmp, k, auth = keys
    settings = _settings(tmp, k, auth)
    service = NodeService(settings, model=PerformanceModel.shipped(), workers=0, publish="tcp://127.0.0.1:*")
    assert service.curve is not None and service.curve.authorized == load_authorized_keys(auth)
    ep = service.publisher.endpoint
    good = Subscriber(ep, curve=_client(k, "peer"))
    intruder = Subscriber(ep, curve=_client(k, "intruder"))
    plain = Subscriber(ep)
    got = {"good": [], "intruder": [], "plain": []}

    def beat() -> None:
        service._send_heartbeat()
        for name, sub in (("good", good), ("intruder", intruder), ("plain", plain)):
            m = sub.recv(timeout_s=0.05)
            if m is not None:
                got[name].append(m)

    try:
        # until the authorized one has 3 (its CURVE handshake waits for the CPU on a loaded machine)
        wait_until(lambda: len(got["good"]) >= 3, step=beat)
        for _ in range(10):  # the others had every chance too
            service._send_heartbeat()
            for name, sub in (("intruder", intruder), ("plain", plain)):
                m = sub.recv(timeout_s=0.05)
                if m is not None:
                    got[name].append(m)
    finally:
        for s in (good, intruder, plain):
            s.close()
        service.close()
    assert len(got["good"]) >= 3 and all(t == "heartbeat" for t, _ in got["good"])
    assert got["intruder"] == [] and got["plain"] == []


def _push(ctx, endpoint, *, curve: CurveConfig | None, server: bool):
    s = ctx.socket(zmq.PUSH)
    s.setsockopt(zmq.LINGER, 0)
    if curve is not None:
        curve.secure_server(s) if server else curve.secure_client(s)
    (s.bind if server else s.connect)(endpoint)
    return s


def _recv_any(link, sender, payload, seconds=WAIT_S):
    """The first record ``link`` gets while ``sender`` keeps offering ``payload`` (None if none
    came). The default is a hang guard only: an admitted sender's record ends the wait. A refusal
    passes a short wait, which can only miss a leak, never fail an admitted sender."""
    got = []

    def offer() -> None:
        try:
            sender.send(payload, zmq.NOBLOCK)
        except zmq.Again:
            pass
        rec = link.recv(timeout=0.1)
        if rec is not None:
            got.append(rec)

    wait_until(lambda: bool(got), timeout_s=seconds, step=offer)
    return got[0] if got else None


def test_bound_tile_socket_admits_only_authorized_senders(keys):
    tmp, k, auth = keys
    node = CurveConfig(keys=load_keypair(k["node"][1]), authorized=load_authorized_keys(auth))
    ctx = zmq.Context.instance()
    link = ZmqTileLink("tcp://127.0.0.1:*", bind=True, curve=node)
    payload = msgpack.packb({"type": "tile", "v": 1}, use_bin_type=True)
    intruder = _push(ctx, link.bound_endpoint, curve=_client(k, "intruder"), server=False)
    plain = _push(ctx, link.bound_endpoint, curve=None, server=False)
    try:
        assert _recv_any(link, intruder, payload, 1.5) is None
        assert _recv_any(link, plain, payload, 1.5) is None
        good = _push(ctx, link.bound_endpoint, curve=_client(k, "peer"), server=False)
        rec = _recv_any(link, good, payload)
        good.close()
    finally:
        intruder.close()
        plain.close()
        link.shutdown()
    assert rec is not None and rec.msg == {"type": "tile", "v": 1}


def test_connecting_tile_socket_is_a_curve_client_of_the_sonar_processor(keys):
    tmp, k, auth = keys
    sonar_keys = load_keypair(k["peer"][1])
    ctx = zmq.Context.instance()
    sonar = CurveConfig(keys=sonar_keys, authorized=frozenset({load_public_key(k["node"][0])}))
    server = ctx.socket(zmq.PUSH)
    server.setsockopt(zmq.LINGER, 0)
    sonar.secure_server(server)
    port = server.bind_to_random_port("tcp://127.0.0.1")
    ep = f"tcp://127.0.0.1:{port}"
    settings = _settings(tmp, k, auth, sonar_server_key_file=k["peer"][0], sonar_endpoint=ep)
    from atr_node.security import curve_from_settings
    from hw import open_links

    curve = curve_from_settings(settings)
    links = open_links(settings.links, curve=curve)
    wrong = ZmqTileLink(ep, curve=CurveConfig(keys=load_keypair(k["intruder"][1]),
                                              server_public_key=sonar_keys.public_key))
    try:
        payload = msgpack.packb({"type": "tile"}, use_bin_type=True)
        rec = _recv_any(links["sonar"], server, payload)
        assert rec is not None and rec.msg == {"type": "tile"}
        assert _recv_any(wrong, server, payload, 1.0) is None  # the intruder is never let in
    finally:
        wrong.shutdown()
        links["sonar"].shutdown()
        server.close()


def test_curve_misconfiguration_is_a_clear_error(keys, tmp_path):
    tmp, k, auth = keys
    with pytest.raises(LinkSpecError, match="server's public key"):
        ZmqTileLink("tcp://127.0.0.1:5999", curve=CurveConfig(keys=load_keypair(k["node"][1])))
    cfg = tmp_path / "half.toml"
    cfg.write_text(f'[links]\ncurve_authorized_dir = "{auth}"\n')
    from atr_node.security import curve_from_settings

    with pytest.raises(ConfigError, match="curve_authorized_dir"):
        curve_from_settings(load_settings(cfg))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ConfigError, match="nobody could connect"):
        load_authorized_keys(empty)


# -- the systemd unit -----------------------------------------------------------------------

def _unit() -> dict[str, list[str]]:
    values: dict[str, list[str]] = {}
    for line in (REPO / "systemd" / "atr-node.service").read_text().splitlines():
        line = line.strip()
        if not line or line.startswith(("#", "[")) or "=" not in line:
            continue
        k, v = line.split("=", 1)
        values.setdefault(k.strip(), []).append(v.strip())
    return values


def test_systemd_unit_is_unprivileged_read_only_and_device_restricted():
    u = _unit()
    one = {k: v[-1] for k, v in u.items()}
    assert one["User"] not in ("root", "0") and one["Group"] not in ("root", "0")
    assert one["NoNewPrivileges"] == "yes"
    assert one["ProtectSystem"] == "strict" and one["ProtectHome"] == "yes" and one["PrivateTmp"] == "yes"
    assert one["CapabilityBoundingSet"] == "" and one["AmbientCapabilities"] == ""
    assert one["DevicePolicy"] == "closed"
    assert all(re.fullmatch(r"/dev/tty(S|USB|ACM)\d+ rw?", d) for d in u["DeviceAllow"]), u["DeviceAllow"]
    # the only writable path is the node's data directory, the default of node.data_dir
    assert u["ReadWritePaths"] == [load_settings(None).node.data_dir] == ["/var/lib/atr-node"]
    assert one["StateDirectory"] == "atr-node"


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_systemd_analyze_security_rates_the_unit_ok():
    r = subprocess.run(["systemd-analyze", "security", "--offline=yes", str(REPO / "systemd" / "atr-node.service")],
                       capture_output=True, text=True, timeout=WAIT_S)
    m = re.search(r"Overall exposure level for atr-node.service: ([0-9.]+)", r.stdout)
    if m is None:
        pytest.skip(f"systemd-analyze security --offline unsupported here: {r.stderr.strip()[:200]}")
    assert float(m.group(1)) <= 3.0, r.stdout[-2000:]
