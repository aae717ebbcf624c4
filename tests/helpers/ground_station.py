"""A bare ground station for tests that talk to the mock autopilot without MAVSDK."""

import socket
import time

from pymavlink.dialects.v20 import common as mavlink


class Client:
    """A ground station on 127.0.0.1:port: receives everything the mock sends there."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.mav = mavlink.MAVLink(None, srcSystem=245, srcComponent=190)
        self.parser = mavlink.MAVLink(None)
        self.peer = None
        self.inbox = []

    def recv(self, kind: str, timeout_s: float = 2.0, where=lambda m: True):
        """The first message of ``kind`` (oldest first) matching ``where``, or None."""
        deadline = time.monotonic() + timeout_s
        while True:
            for i, msg in enumerate(self.inbox):
                if msg.get_type() == kind and where(msg):
                    return self.inbox.pop(i)
            if time.monotonic() >= deadline:
                return None
            try:
                data, self.peer = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            self.inbox += [m for m in self.parser.parse_buffer(data) or []
                           if m.get_type() not in ("ATTITUDE", "LOCAL_POSITION_NED",
                                                   "GLOBAL_POSITION_INT")]

    def send(self, msg) -> None:
        assert self.peer is not None, "receive something first, to learn the mock's port"
        self.sock.sendto(msg.pack(self.mav), self.peer)

    def command(self, cmd: int, *params: float, target=(1, 1)):
        p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
        self.send(self.mav.command_long_encode(*target, cmd, 0, *p))
        ack = self.recv("COMMAND_ACK", 1.0, where=lambda m: m.command == cmd)
        return None if ack is None else ack.result

    def set_mode(self, mode) -> int | None:
        """Ask for a PX4 mode (a ``sitl.autopilot.Px4Mode``), as MAVSDK does; the ACK's
        result, None without one."""
        return self.command(mavlink.MAV_CMD_DO_SET_MODE, 1, mode.main, mode.sub)

    def setpoint(self, yaw_rate_rad_s: float = 0.0, forward_m_s: float = 0.0) -> None:
        """A body-frame velocity and yaw-rate setpoint, as MAVSDK's offboard sends it."""
        self.send(self.mav.set_position_target_local_ned_encode(
            0, 1, 1, mavlink.MAV_FRAME_BODY_NED, 1479, 0, 0, 0, forward_m_s, 0, 0, 0, 0, 0, 0,
            yaw_rate_rad_s))

    def close(self) -> None:
        self.sock.close()
