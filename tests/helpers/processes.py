"""Shared by the SITL and service tests: free ports, and stopping a process with SIGTERM."""

import signal
import socket
import subprocess
import time


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nothing is bound to right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop_with_sigterm(proc: subprocess.Popen, timeout_s: float = 5.0) -> tuple[int, float]:
    """SIGTERM ``proc``; its exit code and how long it took to exit (killed if it hangs)."""
    t0 = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    try:
        code = proc.wait(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.kill()
    return code, time.monotonic() - t0
