"""systemd's notify protocol (sd_notify), without libsystemd.

systemd passes a unix datagram socket in ``NOTIFY_SOCKET`` (a path, or ``@name`` for the
abstract namespace); each datagram is newline-separated ``KEY=VALUE`` lines such as
``READY=1``, ``WATCHDOG=1`` or ``STATUS=...``. Outside systemd the variable is unset and
:func:`notify` does nothing.
"""

from __future__ import annotations

import os
import socket

__all__ = ["notify"]


def notify(*lines: str, env: dict[str, str] | None = None) -> bool:
    """Send ``lines`` (e.g. ``"READY=1"``) to systemd; False when not under systemd."""
    address = (env if env is not None else os.environ).get("NOTIFY_SOCKET")
    if not address:
        return False
    if address.startswith("@"):
        address = "\0" + address[1:]
    payload = "\n".join(lines).encode()
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
            sock.sendto(payload, address)
    except OSError:
        return False
    return True
