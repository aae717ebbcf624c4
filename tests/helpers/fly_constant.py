"""Test helper process: the offboard controller fed a constant turn decision.

    python tests/helpers/fly_constant.py PORT YAW_RATE_DEG_S

Stands in for the vision thread of ``companion run`` so a test can send SIGTERM to a
real process holding a real MAVSDK session.
"""

import logging
import sys
import threading
import time

from companion.config import Config, MavlinkConfig, OffboardConfig
from companion.control.offboard import OffboardController, run_until_signal
from companion.control.policy import TurnCommand


def main() -> int:
    port, rate = int(sys.argv[1]), float(sys.argv[2])
    logging.basicConfig(level=logging.INFO, stream=sys.stdout, format="%(message)s")
    logging.getLogger("mavsdk").setLevel(logging.WARNING)
    config = Config(mavlink=MavlinkConfig(url=f"udpin://127.0.0.1:{port}", connect_timeout_s=10),
                    offboard=OffboardConfig(enabled=True))
    controller = OffboardController(config)

    def feed() -> None:  # a 15 fps "camera" always deciding the same turn
        while True:
            controller.submit(TurnCommand("right" if rate > 0 else "left", rate, rate), rate)
            time.sleep(1 / 15)

    threading.Thread(target=feed, daemon=True).start()
    return run_until_signal(controller)


if __name__ == "__main__":
    sys.exit(main())
