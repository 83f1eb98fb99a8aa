"""systemd readiness and watchdog notifications (``Type=notify``, ``WatchdogSec=``).

Sends datagrams to ``$NOTIFY_SOCKET`` as ``sd_notify(3)`` does; without it (not under
systemd) every call is a no-op. The node sends ``READY=1`` once its links are open,
``WATCHDOG=1`` from its main loop (so a hung loop gets the service restarted), ``STATUS=...``
with a one-line summary, and ``STOPPING=1`` when it drains on SIGTERM.
"""

from __future__ import annotations

import os
import socket


class Notifier:
    def __init__(self, address: str | None = None) -> None:
        addr = address if address is not None else os.environ.get("NOTIFY_SOCKET", "")
        self._sock = None
        if addr:
            if addr.startswith("@"):  # abstract namespace
                addr = "\0" + addr[1:]
            self._addr = addr
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        usec = os.environ.get("WATCHDOG_USEC")
        self.watchdog_s = int(usec) / 1e6 if usec and usec.isdigit() else None

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, state: str) -> bool:
        if self._sock is None:
            return False
        try:
            self._sock.sendto(state.encode(), self._addr)
            return True
        except OSError:
            return False

    def ready(self) -> bool:
        return self.notify("READY=1")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
