"""A mock PX4 autopilot speaking real MAVLink (pymavlink) over UDP on 127.0.0.1.

Test and simulation only; never needed on the drone. It behaves on the network like PX4
SITL's offboard link (``../shared/PX4-NOTES.md``): it sends from its own port to
127.0.0.1:PORT (default 14540, where MAVSDK listens with ``udpin://...:14540``) and answers
whoever talks to it, so MAVSDK, MAVProxy or QGroundControl can connect::

    python -m sitl.autopilot --port 14540

What it enforces, as PX4 does:

- OFFBOARD is entered only while setpoints stream (the newest one younger than
  ``1 / min_setpoint_rate_hz``). In the air without a stream, DO_SET_MODE is acked
  ACCEPTED but the mode does not change; disarmed, the mode changes and arming is then
  refused (TEMPORARILY_REJECTED).
- Setpoints stopping for longer than COM_OF_LOSS_T in OFFBOARD → failsafe mode (AUTO.RTL
  with PX4's default parameters).
- Arming is refused for ``arm_ready_s`` after boot (estimator not yet healthy).

SET_POSITION_TARGET_LOCAL_NED (body or local frame, velocity + yaw rate) flies the
vehicle with a PX4 multicopter's response (:mod:`sitl.multicopter`: dead times, lags,
tilt with acceleration), and its pose goes out as LOCAL_POSITION_NED, ATTITUDE and
GLOBAL_POSITION_INT. Every setpoint received is recorded (time, frame, velocity, yaw
rate), as are NAMED_VALUE_FLOAT and STATUSTEXT messages, so tests assert on what crossed
the wire. Malformed, unknown or wrong-target messages are ignored with a log line. It knows
nothing of rooms or obstacles.

Time: by default the vehicle moves in real time. With ``lockstep`` it moves only when
:meth:`MockAutopilot.advance` is called (a simulation that takes longer than real time to
draw a camera frame steps the vehicle by one frame period each time), and every rule above
runs on that simulated clock, which is also the ``time_boot_ms`` of its telemetry and
paces every stream (a heartbeat also goes out after a real second without one, so the link
stays up while nobody advances the clock). Commands are answered at once, in real time.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import random
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from sitl import multicopter

log = logging.getLogger("sitl.autopilot")

SYSTEM_ID = 1
COMPONENT_ID = 1
HOME_LAT_DEG = 47.397742  # PX4 SITL's default home
HOME_LON_DEG = 8.545594
EARTH_RADIUS_M = 6_371_000.0

# SET_POSITION_TARGET_LOCAL_NED.type_mask bits (MAVLink POSITION_TARGET_TYPEMASK).
_IGNORE_VX, _IGNORE_VY, _IGNORE_VZ = 8, 16, 32
_IGNORE_YAW_RATE = 2048
_BODY_FRAMES = (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_FRD)
_SUPPORTED_FRAMES = (mavlink.MAV_FRAME_LOCAL_NED, *_BODY_FRAMES)

FORCE_DISARM_MAGIC = 21196

CLOCK_TIE_S = 1e-6
"""s: two simulated times this close are the same instant. Dead times and the offboard
climb are whole simulation steps, so comparisons fall on ties, and the rounding of a clock
summed step by step (which differs with how long the run has been going) must not decide
them."""


@dataclass(frozen=True)
class Px4Mode:
    """A PX4 flight mode: main mode and sub mode, as packed into HEARTBEAT.custom_mode."""

    main: int
    sub: int = 0

    @property
    def custom_mode(self) -> int:
        """HEARTBEAT.custom_mode: main mode in bits 16-23, sub mode in bits 24-31."""
        return (self.main << 16) | (self.sub << 24)

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> Px4Mode:
        return cls((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)

    @property
    def name(self) -> str:
        return MODE_NAMES.get(self, f"MODE({self.main},{self.sub})")


MANUAL = Px4Mode(1)
ALTCTL = Px4Mode(2)
POSCTL = Px4Mode(3)
TAKEOFF = Px4Mode(4, 2)
HOLD = Px4Mode(4, 3)  # AUTO.LOITER, which MAVSDK and QGC call Hold
MISSION = Px4Mode(4, 4)
RTL = Px4Mode(4, 5)
LAND = Px4Mode(4, 6)
ACRO = Px4Mode(5)
OFFBOARD = Px4Mode(6)
STABILIZED = Px4Mode(7)
MODE_NAMES = {
    MANUAL: "MANUAL", ALTCTL: "ALTCTL", POSCTL: "POSCTL", TAKEOFF: "AUTO.TAKEOFF",
    HOLD: "AUTO.LOITER", MISSION: "AUTO.MISSION", RTL: "AUTO.RTL", LAND: "AUTO.LAND",
    ACRO: "ACRO", OFFBOARD: "OFFBOARD", STABILIZED: "STABILIZED",
}


@dataclass(frozen=True)
class AutopilotParams:
    """Behaviour knobs; defaults are PX4's as observed (PX4-NOTES.md)."""

    com_of_loss_t_s: float = 1.0  # COM_OF_LOSS_T
    offboard_loss_mode: Px4Mode = RTL  # failsafe target with PX4's default parameters
    min_setpoint_rate_hz: float = 2.0  # offboard needs a stream faster than this
    arm_ready_s: float = 3.0  # arming is TEMPORARILY_REJECTED before this
    takeoff_alt_m: float = 2.5  # MIS_TAKEOFF_ALT
    takeoff_overshoot_m: float = 0.0  # PX4 levelled off 0.6 m above a 1.2 m request
    climb_rate_m_s: float = 1.0
    response: multicopter.Response = multicopter.Response()
    yaw_drift_deg_s: float = 0.0  # heading drift after takeoff (PX4: ~1°/s, settling ...
    yaw_drift_tau_s: float = 4.0  # ... away over the first seconds)
    offboard_climb_m_s: float = 0.0  # altitude creep in offboard (PX4: 0.2 m in 6 s) ...
    offboard_climb_s: float = 6.0  # ... for this long after offboard is entered
    boot_yaw_deg: float = 0.0  # heading at boot; the local frame's origin is where it boots
    boot_in_air: bool = False  # start armed, hovering at takeoff_alt_m in Hold
    sim_rate_hz: float = 100.0
    lockstep: bool = False  # the vehicle moves only in advance() (module docstring)


@dataclass(frozen=True)
class SetpointRecord:
    """One SET_POSITION_TARGET_LOCAL_NED as received."""

    t_s: float  # time.monotonic() at reception
    sim_t_s: float  # the autopilot's own clock at reception (s since boot)
    frame: int
    type_mask: int
    vx_m_s: float
    vy_m_s: float
    vz_m_s: float
    yaw_rate_deg_s: float
    mode: str  # the autopilot's mode when it arrived


@dataclass
class VehicleState:
    """The vehicle: its motion (:class:`sitl.multicopter.Motion`, NED frame, heading in
    degrees from north) and what the autopilot says of it."""

    motion: multicopter.Motion
    armed: bool = False
    landed_state: int = mavlink.MAV_LANDED_STATE_ON_GROUND
    mode: Px4Mode = HOLD
    drift_from_s: float | None = None  # when the heading drift began (takeoff complete)
    offboard_from_s: float | None = None  # when OFFBOARD was last entered
    hold_at: tuple[float, float, float] | None = None  # where Hold (AUTO.LOITER) began

    @property
    def in_air(self) -> bool:
        return self.landed_state != mavlink.MAV_LANDED_STATE_ON_GROUND


@dataclass
class _Stream:
    interval_s: float
    next_t: float = 0.0


# message id → default interval (s), like PX4's onboard link.
_POSE_STREAMS = (mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink.MAVLINK_MSG_ID_ATTITUDE,
                 mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
_DEFAULT_STREAMS = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 1 / 50,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1 / 20,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 1 / 20,
}


class MockAutopilot:
    """A PX4-like autopilot on UDP; use as a context manager or call start()/stop()."""

    def __init__(
        self, port: int = 14540, params: AutopilotParams | None = None, host: str = "127.0.0.1"
    ):
        self.params = params or AutopilotParams()
        self._target = (host, port)
        self._host = host
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self._peers: set[tuple[str, int]] = set()
        self._tx = mavlink.MAVLink(None, srcSystem=SYSTEM_ID, srcComponent=COMPONENT_ID)
        self._rx = mavlink.MAVLink(None)
        self._rx.robust_parsing = True
        self._streams = {mid: _Stream(iv) for mid, iv in _DEFAULT_STREAMS.items()}
        self._params = {"COM_OF_LOSS_T": self.params.com_of_loss_t_s,
                        "MIS_TAKEOFF_ALT": self.params.takeoff_alt_m}
        self.vehicle = VehicleState(multicopter.Motion(yaw_deg=self.params.boot_yaw_deg))
        if self.params.boot_in_air:
            self.vehicle.armed = True
            self.vehicle.landed_state = mavlink.MAV_LANDED_STATE_IN_AIR
            self.vehicle.motion.down_m = -self.params.takeoff_alt_m
        self._boot_t = time.monotonic()
        self._sim_t = 0.0  # lockstep: the simulated time since boot
        self._heartbeat_wall_s = 0.0
        self._last_setpoint: SetpointRecord | None = None
        self.setpoints: list[SetpointRecord] = []
        self.named_values: list[tuple[float, str, float]] = []
        self.obstacle_distances: list[tuple[float, dict]] = []  # (t, OBSTACLE_DISTANCE)
        self.statustexts: list[tuple[float, int, str]] = []
        self.mode_changes: list[tuple[float, str, str]] = []  # (t, mode name, why)
        self.acks: list[tuple[float, int, int]] = []  # (t, command, result)
        self.on_event: Callable[[str], None] = lambda text: None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> MockAutopilot:
        if self._thread is not None:
            return self  # already running
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((self._host, 0))
        self._sock.settimeout(0.002)
        self._boot_t = time.monotonic()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="mock-autopilot", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._sock is not None:
            self._sock.close()
        self._thread = self._sock = None

    def __enter__(self) -> MockAutopilot:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def local_port(self) -> int:
        """The UDP port the autopilot sends from (PX4 uses 14580)."""
        return self._sock.getsockname()[1]

    # ------------------------------------------------------------------ test-facing
    @property
    def mode(self) -> Px4Mode:
        with self._lock:
            return self.vehicle.mode

    @property
    def yaw_deg(self) -> float:
        with self._lock:
            return self.vehicle.motion.yaw_deg

    @property
    def sim_time_s(self) -> float:
        """The autopilot's clock: seconds since boot, simulated in lockstep."""
        with self._lock:
            return self._now()

    def _now(self) -> float:
        return self._sim_t if self.params.lockstep else time.monotonic() - self._boot_t

    def advance(self, dt_s: float) -> float:
        """Lockstep only: move the vehicle ``dt_s`` of simulated time (at ``sim_rate_hz``),
        then send its pose; returns the new simulated time."""
        if not self.params.lockstep:
            raise RuntimeError("advance() needs AutopilotParams(lockstep=True)")
        with self._lock:
            steps = max(1, round(dt_s * self.params.sim_rate_hz))
            for _ in range(steps):
                self._sim_t += dt_s / steps
                self._step(dt_s / steps, self._sim_t)
            self._send_streams(self._sim_t, skip=_POSE_STREAMS)
            self.send_pose()  # the new pose once, whatever the streams' rates
            return self._sim_t

    def send_pose(self) -> None:
        """Send LOCAL_POSITION_NED, ATTITUDE and GLOBAL_POSITION_INT now (lock-step: again,
        for a receiver that dropped them)."""
        with self._lock:
            for mid in _POSE_STREAMS:
                self._send(self._telemetry(mid))

    def pilot_set_mode(self, mode: Px4Mode) -> None:
        """The pilot flips a mode switch on the RC: always wins, no stream needed."""
        with self._lock:
            self._set_mode(mode, "pilot")

    def setpoints_since(self, t_s: float) -> list[SetpointRecord]:
        with self._lock:
            return [s for s in self.setpoints if s.t_s >= t_s]

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Poll ``predicate`` until true or ``timeout_s`` passes; returns its last value."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.01)
        return bool(predicate())

    # ------------------------------------------------------------------ main loop
    def _run(self) -> None:
        last = time.monotonic()
        dt_sim = 1.0 / self.params.sim_rate_hz
        while not self._stop.is_set():
            self._receive()
            now = time.monotonic()
            if now - last >= dt_sim:
                with self._lock:
                    if not self.params.lockstep:
                        self._step(now - last, self._now())
                        self._send_streams(self._now())
                    elif now - self._heartbeat_wall_s > 1.0:  # keep the link alive
                        self._send(self._telemetry(mavlink.MAVLINK_MSG_ID_HEARTBEAT))
                last = now

    def _receive(self) -> None:
        try:
            data, addr = self._sock.recvfrom(65535)
        except (TimeoutError, BlockingIOError):
            return
        except OSError:
            return
        try:
            msgs = self._rx.parse_buffer(data) or []
        except Exception as exc:  # pymavlink raises on some corrupt frames
            log.info("ignored %d malformed bytes from %s:%d (%s)", len(data), *addr, exc)
            self._rx = mavlink.MAVLink(None)
            self._rx.robust_parsing = True
            return
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                log.info("ignored malformed bytes from %s:%d", *addr)
                continue
            self._peers.add(addr)
            with self._lock:
                try:
                    self._handle(msg, addr)
                except Exception:  # never let one message kill the autopilot
                    log.exception("error handling %s; ignored", msg.get_type())

    def _send(self, msg, addr: tuple[str, int] | None = None) -> None:
        if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            self._heartbeat_wall_s = time.monotonic()
        buf = msg.pack(self._tx)
        self._tx.seq = (self._tx.seq + 1) % 256
        targets = [addr] if addr else {self._target, *self._peers}
        for a in targets:
            with contextlib.suppress(OSError):  # nobody listening yet: UDP, like PX4
                self._sock.sendto(buf, a)

    # ------------------------------------------------------------------ vehicle model
    def _set_mode(self, mode: Px4Mode, why: str) -> None:
        if mode == self.vehicle.mode:
            return
        self.vehicle.mode = mode
        self.vehicle.offboard_from_s = None
        m = self.vehicle.motion
        self.vehicle.hold_at = (m.north_m, m.east_m, m.down_m) if mode == HOLD else None
        self.mode_changes.append((time.monotonic(), mode.name, why))
        log.info("mode %s (%s)", mode.name, why)
        self.on_event(f"mode {mode.name} ({why})")
        if mode == TAKEOFF and self.vehicle.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND:
            self.vehicle.landed_state = mavlink.MAV_LANDED_STATE_TAKEOFF

    def _offboard_stream_alive(self, now: float) -> bool:
        sp = self._last_setpoint
        return sp is not None and now - sp.sim_t_s <= 1.0 / self.params.min_setpoint_rate_hz

    def _setpoint_at(self, t: float) -> SetpointRecord | None:
        """The newest setpoint received at or before ``t`` (simulated s): what the vehicle
        answers now, after the response's dead time.

        "At" within :data:`CLOCK_TIE_S`: ``t`` often falls on a setpoint's own time."""
        for sp in reversed(self.setpoints):
            if sp.sim_t_s <= t + CLOCK_TIE_S:
                return sp
        return None

    def _step(self, dt: float, now: float) -> None:
        """Advance the vehicle ``dt`` s to ``now`` (the autopilot's clock)."""
        v, p, r = self.vehicle, self.params, self.params.response
        m = v.motion
        sp = self._last_setpoint
        if v.mode == OFFBOARD and sp is not None and now - sp.sim_t_s > p.com_of_loss_t_s:
            self._set_mode(p.offboard_loss_mode, "offboard setpoints lost")
            self._statustext(mavlink.MAV_SEVERITY_CRITICAL, "Failsafe: offboard lost")
        cmd_v = (0.0, 0.0, 0.0)
        cmd_yaw_rate = 0.0
        if not v.armed or not v.in_air:
            pass
        elif v.mode == OFFBOARD:
            cmd_v = self._setpoint_command(self._setpoint_at(now - r.velocity_dead_s))[0]
            if v.offboard_from_s is None:
                v.offboard_from_s = now
            # The climb is whole steps long: one more must not hang on the clock's rounding.
            if now - v.offboard_from_s < p.offboard_climb_s - CLOCK_TIE_S:
                cmd_v = (cmd_v[0], cmd_v[1], cmd_v[2] - p.offboard_climb_m_s)
            cmd_yaw_rate = self._setpoint_command(self._setpoint_at(now - r.yaw_dead_s))[1]
        elif v.mode == TAKEOFF:
            target = -(p.takeoff_alt_m + p.takeoff_overshoot_m)
            cmd_v = (0.0, 0.0, max(-p.climb_rate_m_s, min(p.climb_rate_m_s, target - m.down_m)))
            if m.down_m <= target + 0.1:
                v.landed_state = mavlink.MAV_LANDED_STATE_IN_AIR
                v.drift_from_s = now
                self._set_mode(HOLD, "takeoff complete")
        elif v.mode == HOLD and v.hold_at is not None:  # loiter: back to where Hold began
            cmd_v = tuple(max(-1.0, min(1.0, h - x)) for h, x in zip(
                v.hold_at, (m.north_m, m.east_m, m.down_m), strict=True))
        elif v.mode == LAND or (v.mode == RTL and math.hypot(m.north_m, m.east_m) < 0.5):
            cmd_v = (0.0, 0.0, p.climb_rate_m_s)
            v.landed_state = mavlink.MAV_LANDED_STATE_LANDING
        elif v.mode == RTL:
            d = math.hypot(m.north_m, m.east_m)
            cmd_v = (-m.north_m / d, -m.east_m / d, 0.0)
        if v.drift_from_s is not None and p.yaw_drift_deg_s:
            cmd_yaw_rate += p.yaw_drift_deg_s * math.exp(
                -(now - v.drift_from_s) / p.yaw_drift_tau_s) / r.yaw_gain
        multicopter.step(m, cmd_v, cmd_yaw_rate, dt, r, move=v.armed and v.in_air)
        if m.down_m >= 0.0 and v.landed_state == mavlink.MAV_LANDED_STATE_LANDING:
            v.landed_state = mavlink.MAV_LANDED_STATE_ON_GROUND
            v.armed = False  # PX4 auto-disarms on touchdown
            multicopter.step(m, cmd_v, 0.0, dt, r, move=False)
            self._set_mode(HOLD, "landed")

    def _setpoint_command(self, sp: SetpointRecord | None
                          ) -> tuple[tuple[float, float, float], float]:
        """Velocity (NED, m/s) and yaw rate (deg/s) a setpoint asks for; zero if unusable."""
        if sp is None or sp.frame not in _SUPPORTED_FRAMES:
            return (0.0, 0.0, 0.0), 0.0
        vel = [0.0, 0.0, 0.0]
        for i, bit, value in ((0, _IGNORE_VX, sp.vx_m_s), (1, _IGNORE_VY, sp.vy_m_s),
                              (2, _IGNORE_VZ, sp.vz_m_s)):
            if not sp.type_mask & bit:
                vel[i] = value
        if sp.frame in _BODY_FRAMES:
            yaw = math.radians(self.vehicle.motion.yaw_deg)
            c, s = math.cos(yaw), math.sin(yaw)
            vel[0], vel[1] = c * vel[0] - s * vel[1], s * vel[0] + c * vel[1]
        yaw_rate = 0.0 if sp.type_mask & _IGNORE_YAW_RATE else sp.yaw_rate_deg_s
        return (vel[0], vel[1], vel[2]), yaw_rate

    # ------------------------------------------------------------------ telemetry
    def _time_boot_ms(self) -> int:
        return int(self._now() * 1000) & 0xFFFFFFFF

    def _send_streams(self, now: float, skip: tuple[int, ...] = ()) -> None:
        """Send the streams that are due at ``now`` (the autopilot's clock)."""
        for mid, stream in self._streams.items():
            if mid in skip:
                continue
            if stream.interval_s > 0 and now >= stream.next_t:
                stream.next_t = now + stream.interval_s
                msg = self._telemetry(mid)
                if msg is not None:
                    self._send(msg)

    def _telemetry(self, mid: int):
        v, t = self.vehicle, self._time_boot_ms()
        m = v.motion
        vn, ve, vd = m.velocity(self.params.response)
        if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            if v.armed:
                base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            status = mavlink.MAV_STATE_ACTIVE if v.armed else mavlink.MAV_STATE_STANDBY
            return self._tx.heartbeat_encode(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base,
                v.mode.custom_mode, status)
        if mid == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
            sensors = 0x3FFFFFFF
            return self._tx.sys_status_encode(sensors, sensors, sensors, 250, 16000, -1, 90,
                                              0, 0, 0, 0, 0, 0)
        if mid == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            return self._tx.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED,
                                                      v.landed_state)
        if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE:
            return self._tx.attitude_encode(
                t, math.radians(m.roll_deg), math.radians(m.pitch_deg), math.radians(m.yaw_deg),
                0.0, 0.0, math.radians(m.yaw_rate_deg_s))
        if mid == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            return self._tx.local_position_ned_encode(t, m.north_m, m.east_m, m.down_m,
                                                      vn, ve, vd)
        if mid == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            lat = HOME_LAT_DEG + math.degrees(m.north_m / EARTH_RADIUS_M)
            lon = HOME_LON_DEG + math.degrees(
                m.east_m / (EARTH_RADIUS_M * math.cos(math.radians(HOME_LAT_DEG))))
            hdg = int(round((m.yaw_deg % 360.0) * 100)) % 36000
            return self._tx.global_position_int_encode(
                t, int(lat * 1e7), int(lon * 1e7), int((488.0 - m.down_m) * 1000),
                int(-m.down_m * 1000), int(vn * 100), int(ve * 100), int(vd * 100), hdg)
        if mid == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            return self._tx.home_position_encode(
                int(HOME_LAT_DEG * 1e7), int(HOME_LON_DEG * 1e7), 488000, 0.0, 0.0, 0.0,
                [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)
        if mid == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            caps = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
                    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                    | mavlink.MAV_PROTOCOL_CAPABILITY_FLIGHT_TERMINATION)
            return self._tx.autopilot_version_encode(
                caps, 0x010F00FF, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x4D4F434B)
        return None

    def _statustext(self, severity: int, text: str) -> None:
        self._send(self._tx.statustext_encode(severity, text.encode()[:50]))

    # ------------------------------------------------------------------ handlers
    def _handle(self, msg, addr: tuple[str, int]) -> None:
        kind = msg.get_type()
        target_sys = getattr(msg, "target_system", None)
        if target_sys not in (None, 0, SYSTEM_ID):
            log.info("ignored %s for system %d", kind, target_sys)
            return
        if kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._on_setpoint(msg)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            target_comp = msg.target_component
            if target_comp not in (0, COMPONENT_ID):
                log.info("ignored command %d for component %d", msg.command, target_comp)
                return
            result = self._on_command(msg, addr)
            self.acks.append((time.monotonic(), msg.command, result))
            self._send(self._tx.command_ack_encode(msg.command, result, 0, 0,
                                                   msg.get_srcSystem(),
                                                   msg.get_srcComponent()), addr)
        elif kind in ("PARAM_REQUEST_READ", "PARAM_SET", "PARAM_REQUEST_LIST"):
            self._on_param(msg, addr)
        elif kind == "NAMED_VALUE_FLOAT":
            self.named_values.append((time.monotonic(), msg.name, float(msg.value)))
        elif kind == "OBSTACLE_DISTANCE":
            self.obstacle_distances.append((time.monotonic(), msg.to_dict()))
        elif kind == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
            self.statustexts.append((time.monotonic(), msg.severity, text.rstrip("\0")))
            log.info("statustext from %d/%d: %s", msg.get_srcSystem(), msg.get_srcComponent(),
                     text)
        elif kind in ("HEARTBEAT", "PING", "TIMESYNC", "SYSTEM_TIME", "MANUAL_CONTROL"):
            pass  # nothing to do for a mock
        else:
            log.debug("ignored %s", kind)

    def _on_setpoint(self, msg) -> None:
        sp = SetpointRecord(
            t_s=time.monotonic(), sim_t_s=self._now(), frame=msg.coordinate_frame,
            type_mask=msg.type_mask,
            vx_m_s=msg.vx, vy_m_s=msg.vy, vz_m_s=msg.vz,
            yaw_rate_deg_s=math.degrees(msg.yaw_rate), mode=self.vehicle.mode.name)
        if sp.frame not in _SUPPORTED_FRAMES:
            log.info("setpoint in unsupported frame %d; vehicle will hold", sp.frame)
        self.setpoints.append(sp)
        self._last_setpoint = sp

    def _on_command(self, msg, addr: tuple[str, int]) -> int:
        cmd = msg.command
        if msg.get_type() == "COMMAND_INT":
            p = [msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z]
        else:
            p = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6,
                 msg.param7]
        v, now = self.vehicle, self._now()
        accepted, denied = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] >= 0.5:
                if v.armed:
                    return accepted
                if now < self.params.arm_ready_s:
                    return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
                if v.mode == OFFBOARD and not self._offboard_stream_alive(now):
                    return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
                v.armed = True
                self.on_event("armed")
                return accepted
            if v.in_air and int(p[1]) != FORCE_DISARM_MAGIC:
                return denied
            v.armed = False
            v.landed_state = mavlink.MAV_LANDED_STATE_ON_GROUND
            self.on_event("disarmed")
            return accepted
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            if not v.armed:
                return denied
            self._set_mode(TAKEOFF, "takeoff command")
            return accepted
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            if not v.in_air:
                return denied
            self._set_mode(LAND, "land command")
            return accepted
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._set_mode(RTL, "RTL command")
            return accepted
        if cmd == mavlink.MAV_CMD_DO_SET_MODE:
            return self._on_set_mode(int(p[0]), int(p[1]), int(p[2]), now)
        if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            reply = self._telemetry(int(p[0]))
            if reply is None:
                return denied
            self._send(reply, addr)
            return accepted
        if cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._send(self._telemetry(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION), addr)
            return accepted
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            mid, interval_us = int(p[0]), p[1]
            if interval_us < 0:
                self._streams[mid] = _Stream(0.0)
            elif interval_us == 0:
                self._streams[mid] = _Stream(_DEFAULT_STREAMS.get(mid, 0.0))
            elif self._telemetry(mid) is None:
                return denied
            else:
                self._streams[mid] = _Stream(interval_us / 1e6)
            return accepted
        log.info("unsupported command %d", cmd)
        return mavlink.MAV_RESULT_UNSUPPORTED

    def _on_set_mode(self, base_mode: int, main: int, sub: int, now: float) -> int:
        if not base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_UNSUPPORTED
        mode = Px4Mode(main, sub if main == 4 else 0)
        if mode not in MODE_NAMES:
            return mavlink.MAV_RESULT_DENIED
        if mode == OFFBOARD and self.vehicle.armed and not self._offboard_stream_alive(now):
            # As a real PX4 in the air: accepted, but the mode does not change.
            log.info("offboard requested without a setpoint stream; staying in %s",
                     self.vehicle.mode.name)
            return mavlink.MAV_RESULT_ACCEPTED
        if mode == TAKEOFF and not self.vehicle.armed:
            return mavlink.MAV_RESULT_DENIED
        self._set_mode(mode, "DO_SET_MODE")
        return mavlink.MAV_RESULT_ACCEPTED

    def _on_param(self, msg, addr: tuple[str, int]) -> None:
        kind = msg.get_type()
        names = list(self._params)
        if kind == "PARAM_SET":
            name = msg.param_id.rstrip("\0") if isinstance(msg.param_id, str) else ""
            if name not in self._params:
                log.info("ignored PARAM_SET of unknown %r", name)
                return
            self._params[name] = float(msg.param_value)
            if name == "MIS_TAKEOFF_ALT":
                self.params = replace(self.params, takeoff_alt_m=float(msg.param_value))
            if name == "COM_OF_LOSS_T":
                self.params = replace(self.params, com_of_loss_t_s=float(msg.param_value))
            wanted = [name]
        elif kind == "PARAM_REQUEST_READ":
            name = msg.param_id.rstrip("\0") if msg.param_index < 0 else (
                names[msg.param_index] if msg.param_index < len(names) else "")
            if name not in self._params:
                return
            wanted = [name]
        else:
            wanted = names
        for name in wanted:
            self._send(self._tx.param_value_encode(
                name.encode(), self._params[name], mavlink.MAV_PARAM_TYPE_REAL32,
                len(names), names.index(name)), addr)



def _ephemeral_port_range() -> tuple[int, int]:
    """The ports the kernel hands to sockets bound to port 0 (Linux's range, else its default)."""
    try:
        low, high = map(int, Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
    except (OSError, ValueError):
        low, high = 32768, 60999
    return low, high


_port_choice = random.Random()  # its own generator: a test seeding `random` must not pin ports


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nothing is bound to now, outside the ephemeral range.

    Outside it because the port is only reserved by its number: between this call and the
    listener's bind, any socket bound to port 0 (the mock's own, MAVSDK's, another
    process's) could be handed an ephemeral port, and so once in a few thousand calls
    this very one (a CI run failed on it with MAVSDK's BIND_ERROR).
    """
    low, high = _ephemeral_port_range()
    spans = [span for span in (range(20000, low), range(high + 1, 65536)) if len(span) > 100]
    for _ in range(200 if spans else 0):
        span = _port_choice.choice(spans)
        port = _port_choice.choice(span)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # no room outside it
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sitl.autopilot", description=__doc__.split(
        "\n\n")[0])
    parser.add_argument("--port", type=int, default=14540,
                        help="UDP port on 127.0.0.1 to send to (MAVSDK listens there)")
    parser.add_argument("--com-of-loss-t", type=float, default=1.0, metavar="S",
                        help="offboard setpoint loss timeout, seconds (PX4 COM_OF_LOSS_T)")
    parser.add_argument("--arm-ready-s", type=float, default=3.0, metavar="S",
                        help="arming is refused for this long after boot")
    parser.add_argument("--in-air", action="store_true",
                        help="boot armed and hovering in Hold (skip takeoff)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    params = AutopilotParams(com_of_loss_t_s=args.com_of_loss_t, arm_ready_s=args.arm_ready_s,
                             boot_in_air=args.in_air)
    ap = MockAutopilot(args.port, params)
    ap.on_event = lambda text: print(text, flush=True)
    ap.start()
    print(f"mock autopilot: sending to 127.0.0.1:{args.port} from port {ap.local_port}; "
          "Ctrl-C to stop", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        ap.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
