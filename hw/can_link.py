"""CAN frames through python-can: ``socketcan`` aboard, ``virtual`` on the bench (ICD section 2).

Every data frame becomes ``LogRecord(t, link="can", msg={"id": int, "data": bytes, "ext": bool})``
with ``t`` the frame's receive time stamp (kernel time stamp on socketcan). Error frames and
remote frames carry no navigation and are counted, not delivered. The link does not decode:
:class:`hw.can_nav.CanNavDecoder` does, so a recording holds the raw bus.
"""

from __future__ import annotations

import time
from typing import Any

import can

from atr_node.errors import describe
from atr_node.io.atrlog import LogRecord

from .base import Link
from .errors import LinkError, LinkSpecError


def frame_record(msg: can.Message) -> LogRecord:
    """The record of one received data frame."""
    t = msg.timestamp if msg.timestamp and msg.timestamp > 0 else time.time()
    return LogRecord(t=float(t), link="can", msg={"id": int(msg.arbitration_id), "data": bytes(msg.data),
                                                 "ext": bool(msg.is_extended_id)})


class CanLink(Link):
    """Frames from a python-can bus.

    Parameters
    ----------
    interface
        python-can interface name: ``socketcan``, ``virtual``, ``pcan``, ...
    channel
        Channel of that interface: ``can0`` aboard, any name shared with the sender on ``virtual``.
    bus_options
        Passed to ``can.Bus`` (``bitrate``, ``receive_own_messages``, ``can_filters``, ...).
    """

    kind = "can"

    def __init__(self, interface: str, channel: str = "can0", **bus_options: Any) -> None:
        super().__init__(f"{interface}:{channel}")
        if not interface or not isinstance(interface, str):
            raise LinkSpecError(f"CAN link: interface {interface!r}: expected a python-can interface name "
                                f"like 'socketcan' or 'virtual'")
        if interface not in can.VALID_INTERFACES:
            raise LinkSpecError(f"CAN link: unknown interface {interface!r}; python-can knows "
                                f"{', '.join(sorted(can.VALID_INTERFACES))}")
        try:
            self.bus = can.Bus(interface=interface, channel=channel, **bus_options)
        except (can.CanError, OSError, ValueError, TypeError) as exc:
            raise LinkError(f"CAN link {interface}:{channel}: cannot open the bus: {describe(exc)}") from None

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        try:
            msg = self.bus.recv(timeout=timeout)
        except (can.CanError, OSError) as exc:
            raise LinkError(f"CAN link {self.name}: receive failed: {describe(exc)}") from None
        if msg is None:
            return None
        if msg.is_error_frame:
            self.counts["error_frames"] += 1
            return None
        if msg.is_remote_frame:
            self.counts["remote_frames"] += 1
            return None
        self.counts["bytes"] += len(msg.data)
        return frame_record(msg)

    def _shutdown_internal(self) -> None:
        self.bus.shutdown()
