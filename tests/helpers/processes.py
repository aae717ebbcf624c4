"""Shared by the SITL and service tests: free ports, and stopping a process with SIGTERM."""

import signal
import subprocess
import time

from sitl.autopilot import free_udp_port  # noqa: F401  (the tests' import point)


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
