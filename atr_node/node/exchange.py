"""Evidence exchange between nodes on ZeroMQ (issue 11; format in ``atr_node.fusion.exchange``).

::

    own leg commits --> ExchangeGrid --> DeltaPublisher (XPUB, node.exchange_publish)
                                               |  [b"evidence", msgpack delta v1]
    other nodes' PUB --> PeerLink (SUB, node.exchange_peers) --> NodeExchange.pump
                                                                   --> ExchangeGrid.ingest --> contacts

The exchange has its own PUB socket: the autonomy layer's socket (ICD section 3) carries
only what the ICD lists. Ingest happens in the pipeline's thread (``pump`` from the service's
loop), so the grid is never touched by two threads. A delta that fails validation is counted
and logged, never fatal; a duplicated or replayed one is counted and changes nothing. The
ledger (every delta held) goes into each node snapshot (``exchange.msgpack`` in the snapshot
folder), so a node resumed after a crash keeps exchanging and stays exact.
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from pathlib import Path
from typing import Any, Callable, Iterable

import msgpack
import zmq

from ..errors import AtrError, describe
from ..fusion.exchange import TOPIC, EvidenceDelta, decode_delta, encode_delta
from ..fusion.exchange_grid import ExchangeGrid

log = logging.getLogger(__name__)


def attach_exchange(pipeline: Any, *, node: str, on_delta: Callable[[EvidenceDelta], None] | None = None) -> ExchangeGrid:
    """Give ``pipeline`` an :class:`ExchangeGrid` (before its first record): its committed legs
    become deltas (``on_delta``, ``grid.outbox``) and it can ingest other nodes'."""
    if pipeline.grid.n_observations or pipeline.grid.chunk_keys():
        raise AtrError("attach_exchange: the pipeline already holds evidence; attach before the first record")
    grid = ExchangeGrid(pipeline.settings.fusion, gate_m=pipeline.gate_m, detectors=pipeline.enabled, node=node,
                        context=lambda: (pipeline.mission, pipeline.frame), on_delta=on_delta,
                        layers=pipeline.grid.layers)
    pipeline.grid = grid
    return grid


class DeltaPublisher:
    """Publishes this node's deltas as ``[b"evidence", delta]``: an XPUB socket, which sends as
    a PUB does and also hears each peer's subscription (:meth:`subscriptions`), so a caller can
    wait for a peer to be listening instead of for an amount of time (ZeroMQ drops what a PUB
    sends before the subscription arrives)."""

    def __init__(self, endpoint: str, *, context: zmq.Context | None = None, hwm: int = 100000) -> None:
        self._sock = (context or zmq.Context.instance()).socket(zmq.XPUB)
        self._sock.setsockopt(zmq.XPUB_VERBOSE, 1)  # every peer's subscription, not only the first
        self._sock.setsockopt(zmq.LINGER, 1000)
        self._sock.setsockopt(zmq.SNDHWM, hwm)
        self._sock.bind(endpoint)
        self.endpoint = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self.sent = 0
        self._subscriptions = 0

    def subscriptions(self) -> int:
        """Peer subscriptions heard so far (each SUB that subscribed; unsubscriptions are not
        counted). Reads the ones waiting on the socket, without blocking."""
        while not self._sock.closed and self._sock.poll(0):
            if self._sock.recv()[:1] == b"\x01":
                self._subscriptions += 1
        return self._subscriptions

    def send(self, delta: EvidenceDelta) -> None:
        self._sock.send_multipart([TOPIC, encode_delta(delta)])
        self.sent += 1

    def close(self) -> None:
        if not self._sock.closed:
            self._sock.close()


class PeerLink:
    """SUB socket connected to other nodes' exchange endpoints; ``recv`` -> payload or None."""

    def __init__(self, endpoints: Iterable[str], *, context: zmq.Context | None = None) -> None:
        self._sock = (context or zmq.Context.instance()).socket(zmq.SUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.SUBSCRIBE, TOPIC)
        self.endpoints: tuple[str, ...] = ()
        for e in endpoints:
            self.connect(e)

    def connect(self, endpoint: str) -> None:
        self._sock.connect(endpoint)
        self.endpoints += (endpoint,)

    def recv(self, timeout_s: float = 0.0) -> bytes | None:
        if not self._sock.poll(int(timeout_s * 1000)):
            return None
        frames = self._sock.recv_multipart()
        if len(frames) != 2 or frames[0] != TOPIC:
            raise AtrError(f"evidence exchange: expected 2 frames [b'evidence', delta], got {len(frames)} "
                           f"starting {frames[0][:20]!r}")
        return frames[1]

    def close(self) -> None:
        if not self._sock.closed:
            self._sock.close()


class NodeExchange:
    """A pipeline's evidence exchange: publish own deltas, ingest the peers'.

    Parameters
    ----------
    pipeline
        The node's :class:`~atr_node.node.pipeline.Pipeline`, before its first record.
    node : str
        This node's id.
    publish : str
        Endpoint to bind the delta PUB socket to ("" = do not publish).
    peers : iterable of str
        Other nodes' delta endpoints to subscribe to.
    """

    def __init__(self, pipeline: Any, *, node: str, publish: str = "", peers: Iterable[str] = ()) -> None:
        self.pipeline = pipeline
        self.publisher = DeltaPublisher(publish) if publish else None
        peers = tuple(peers)
        self.peers = PeerLink(peers) if peers else None
        self.counters: Counter = Counter()
        self.grid = attach_exchange(pipeline, node=node, on_delta=self._publish)

    def connect(self, endpoint: str) -> None:
        """Subscribe to one more node's delta endpoint."""
        if self.peers is None:
            self.peers = PeerLink(())
        self.peers.connect(endpoint)

    def _publish(self, delta: EvidenceDelta) -> None:
        if self.publisher is not None:
            self.publisher.send(delta)

    def ingest(self, payload: bytes | EvidenceDelta) -> bool:
        """Ingest one delta into the pipeline's grid (counted, logged; never raises on bad input)."""
        grid = self.pipeline.grid
        if grid is not self.grid:  # restored from a snapshot: the ledger did not survive (docs)
            raise AtrError("evidence exchange: the pipeline's grid was replaced (snapshot restore)")
        try:
            new = grid.ingest(payload)
        except AtrError as exc:
            self.counters["rejected"] += 1
            log.warning("evidence delta rejected: %s", describe(exc))
            return False
        self.counters["ingested" if new else "duplicates"] += 1
        return new

    def pump(self, timeout_s: float = 0.0, max_messages: int = 1000) -> int:
        """Ingest the deltas waiting on the peer link; update contacts; return how many were new."""
        if self.peers is None:
            return 0
        new = 0
        for _ in range(max_messages):
            try:
                payload = self.peers.recv(timeout_s if new == 0 else 0.0)
            except AtrError as exc:
                self.counters["rejected"] += 1
                log.warning("evidence exchange: peer message rejected: %s", describe(exc))
                continue
            if payload is None:
                break
            new += self.ingest(payload)
        if new:
            self.pipeline._update_contacts(self.pipeline._last_t)
        return new

    # -- snapshots ---------------------------------------------------------------------------
    FILE = "exchange.msgpack"

    def save(self, folder: str | os.PathLike[str]) -> Path:
        """Write the ledger (every delta, encoded) and its bookkeeping into a snapshot folder,
        atomically (temporary file, fsync, rename)."""
        path = Path(folder) / self.FILE
        body = msgpack.packb({"format": "atr-node exchange ledger", "v": 1, "node": self.grid.node,
                              "state": self.grid.exchange_state(),
                              "deltas": [encode_delta(d) for d in self.grid.ledger.ordered()]}, use_bin_type=True)
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        with open(tmp, "wb") as fh:
            fh.write(body)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        return path

    def restore(self, folder: str | os.PathLike[str] | None) -> bool:
        """After the pipeline was restored from the snapshot in ``folder``: take its grid over
        with the saved ledger. False (the caller switches the exchange off) if the folder has
        no ledger or an unreadable one."""
        path = Path(folder) / self.FILE if folder is not None else None
        if path is None or not path.is_file():
            log.warning("evidence exchange: no ledger in the snapshot %s", folder)
            return False
        try:
            m = msgpack.unpackb(path.read_bytes(), raw=False)
            if m.get("format") != "atr-node exchange ledger" or m.get("v") != 1 or m.get("node") != self.grid.node:
                raise AtrError(f"format {m.get('format')!r} v{m.get('v')!r} of node {m.get('node')!r}")
            deltas = [decode_delta(b) for b in m["deltas"]]
            grid = ExchangeGrid.adopt(self.pipeline.grid, m["state"], deltas, node=self.grid.node,
                                      context=self.grid.context, on_delta=self._publish)
        except (AtrError, ValueError, KeyError, TypeError, msgpack.UnpackException) as exc:
            log.warning("evidence exchange: ledger %s unreadable (%s)", path, exc)
            return False
        self.pipeline.grid = self.grid = grid
        return True

    def close(self) -> None:
        for s in (self.publisher, self.peers):
            if s is not None:
                s.close()
