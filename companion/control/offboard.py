"""The MAVSDK session: connect, watch the vehicle, stream velocity setpoints, clean up.

The imperative shell around :mod:`companion.control.supervisor`. Each tick (at
``offboard.setpoint_rate_hz``, independent of the camera) it reads what MAVSDK's
telemetry says about the vehicle, asks :func:`~companion.control.supervisor.supervise`
what to do, and does it: start or stop offboard, stream the forward speed and yaw rate as
a body-frame velocity setpoint (SET_POSITION_TARGET_LOCAL_NED, frame BODY_NED, type_mask
1479, vertical velocity 0), tell the ground station (STATUSTEXT on each state change, η as
NAMED_VALUE_FLOAT). It also keeps the vehicle's newest pose (:class:`VehiclePose`, from
LOCAL_POSITION_NED and ATTITUDE) for whoever needs it: the simulation renders from it.

Safety, beyond the state machine:

- MAVSDK resends the last setpoint on its own thread at 20 Hz. If this asyncio loop ever
  stalls, that would keep an old turn flying, so a dead-man thread independent of the loop
  replaces the setpoint with zero once the loop has not ticked for ``stale_after_s``.
- :meth:`OffboardController.run` always ends with a zero setpoint and, if offboard was
  engaged, a request for Hold, bounded in time so a SIGTERM exits within a second.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from companion.config import Config
from companion.control import obstacle_distance as od
from companion.control import supervisor as sv
from companion.control.obstacle_distance import ObstacleDistance
from companion.control.policy import TurnCommand

log = logging.getLogger("companion.offboard")

__all__ = ["AutopilotNotFound", "OffboardController", "SentSetpoint", "VehiclePose",
           "run_until_signal"]

# MAVSDK as COMPANION_COMPUTER: the autopilot's system id, component 195 (PX4-NOTES.md).
COMPANION_SYSTEM_ID = 1
COMPANION_COMPONENT_ID = 195
STOP_BUDGET_S = 0.6  # the share of SIGTERM's 1 s the Hold request may take


class AutopilotNotFound(RuntimeError):
    """No autopilot answered at the configured URL within the timeout."""


@dataclass
class _Telemetry:
    """The newest values MAVSDK's subscriptions delivered."""

    armed: bool = False
    in_air: bool = False
    offboard: bool = False
    in_air_known: bool = False  # in_air has been reported at least once


@dataclass(frozen=True)
class VehiclePose:
    """The vehicle's pose as the autopilot reports it, in its local NED frame (origin where
    its estimator started, not anywhere the companion knows). ``attitude_t_us``: the
    ATTITUDE message's time since the autopilot booted; ``position_updates``: how many
    LOCAL_POSITION_NED have arrived."""

    north_m: float
    east_m: float
    down_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    attitude_t_us: int
    position_updates: int


@dataclass(frozen=True)
class SentSetpoint:
    """The newest decision that went out in a setpoint: the frame time it was decided on
    (``t_s``, on the controller's clock), the ``time.monotonic()`` it was handed to MAVSDK,
    and what the setpoint carried."""

    t_s: float
    monotonic_s: float
    forward_m_s: float
    yaw_rate_deg_s: float


class OffboardController:
    """Streams the newest turn decision to PX4 over MAVSDK, within the supervisor's rules.

    ``submit()`` and ``enable()`` may be called from any thread (the vision thread);
    ``run()`` is the asyncio task that owns the MAVSDK session. ``clock`` is the time
    decisions and the supervisor run on (monotonic seconds; a simulation run in lock-step
    with its autopilot passes the simulated vehicle time).
    """

    def __init__(self, config: Config, clock: Callable[[], float] = time.monotonic):
        self.config = config
        self.clock = clock
        self._lock = threading.Lock()
        self._decision: sv.Decision | None = None
        self._obstacle_distance: tuple[float, ObstacleDistance | None] | None = None
        self._enable_requested = False
        self.state = sv.initial_state(config.offboard)
        self.events: list[str] = []  # every state-change message, in order (also logged)
        self.connected = False  # the autopilot's link, as MAVSDK sees it
        # Set by submit() so a new decision goes out at once, not at the next tick.
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None
        self.pose: VehiclePose | None = None  # newest telemetry, once both kinds arrived
        self.sent: SentSetpoint | None = None
        # The frame time (t_s) of the decision the newest completed supervisor tick acted
        # on: a lock-stepped simulation waits for its frame's. (A count of ticks would not
        # do: a tick under way when a frame is submitted completes on the decision before.)
        self.ticked_t_s: float | None = None

    # ------------------------------------------------------------------ any thread
    def submit(self, command: TurnCommand, eta_deg: float | None = None,
               t_s: float | None = None,
               obstacle_distance: ObstacleDistance | None = None,
               range_m: float | None = None, path_m: float | None = None,
               confirmed: bool = True,
               contacts_m: tuple[tuple[float, float], ...] = ()) -> None:
        """Hand over the newest decision (``t_s``: when its frame was taken, on ``clock``).
        It carries the heading the autopilot reports now, the frame's a few ms ago, the
        frame's OBSTACLE_DISTANCE sectors, if it measured any, its ranges, whether the
        tracker confirmed its obstacle and its floor contacts with the floor behind them
        (:class:`~companion.control.supervisor.Decision`)."""
        pose = self.pose
        decision = sv.Decision(self.clock() if t_s is None else t_s, command, eta_deg,
                               None if pose is None else pose.yaw_deg, range_m, path_m,
                               confirmed, contacts_m)
        with self._lock:
            self._decision = decision
            self._obstacle_distance = (decision.t_s, obstacle_distance)
            loop, wake = self._loop, self._wake
        if loop is not None and wake is not None:
            with contextlib.suppress(RuntimeError):  # the loop has just closed
                loop.call_soon_threadsafe(wake.set)

    def camera_height_m(self) -> float | None:
        """The camera's height above the floor as the autopilot reports it: the altitude
        above its local origin (where its estimator started, on the floor indoors), None
        before telemetry or on the ground."""
        pose = self.pose
        return -pose.down_m if pose is not None and -pose.down_m > 0.05 else None

    def enable(self) -> None:
        """Allow offboard again after a release (pilot override, stall, link loss)."""
        with self._lock:
            self._enable_requested = True

    # ------------------------------------------------------------------ the session
    async def run(self, stop: asyncio.Event) -> None:
        """Connect, supervise until ``stop`` is set, then leave the vehicle safe.

        Raises :class:`AutopilotNotFound` if nothing answers within
        ``mavlink.connect_timeout_s``.
        """
        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

        cfg = self.config
        _route_mavsdk_log()
        with self._lock:
            self._loop, self._wake = asyncio.get_running_loop(), asyncio.Event()
        mavsdk_config = Configuration.create_with_component_type(
            ComponentType.COMPANION_COMPUTER)
        async with Mavsdk(mavsdk_config) as mavsdk:
            await mavsdk.add_any_connection(cfg.mavlink.url)
            self._event(f"waiting for the autopilot on {cfg.mavlink.url}")
            system = await _first_autopilot(mavsdk, cfg.mavlink.connect_timeout_s, stop)
            if system is None:
                if stop.is_set():
                    return
                raise AutopilotNotFound(
                    f"no autopilot answered on {cfg.mavlink.url} within "
                    f"{cfg.mavlink.connect_timeout_s:g} s (is it powered and is the URL right?)")
            self._event("autopilot connected")
            if not cfg.offboard.enabled:
                self._event("offboard.enabled is false: deciding only, never commanding")
            session = _Session(self, system)
            try:
                await session.watch()
                if cfg.offboard.sim_arm_and_takeoff:
                    await session.arm_and_take_off(stop)
                await session.supervise(stop)
            finally:
                await session.close()

    # ------------------------------------------------------------------ helpers
    def _take(self) -> tuple[sv.Decision | None, bool]:
        with self._lock:
            enable, self._enable_requested = self._enable_requested, False
            return self._decision, enable

    def _event(self, text: str) -> None:
        self.events.append(text)
        log.info("%s", text)


def _route_mavsdk_log() -> None:
    """MAVSDK's C++ log lines go to the ``mavsdk`` Python logger instead of stderr."""
    from mavsdk.logging import LogLevel, log_subscribe

    levels = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.INFO,
              LogLevel.WARN: logging.WARNING, LogLevel.ERROR: logging.ERROR}
    mavsdk_log = logging.getLogger("mavsdk")

    def forward(level, message, _file, _line) -> bool:
        mavsdk_log.log(levels.get(level, logging.INFO), "%s", message)
        return True  # handled: suppress MAVSDK's own printing

    log_subscribe(forward)


async def _first_autopilot(mavsdk, timeout_s: float, stop: asyncio.Event):
    """``first_autopilot`` that a stop request interrupts."""
    wait = asyncio.ensure_future(mavsdk.first_autopilot(timeout_s=timeout_s))
    stopped = asyncio.ensure_future(stop.wait())
    done, _ = await asyncio.wait({wait, stopped}, return_when=asyncio.FIRST_COMPLETED)
    stopped.cancel()
    if wait in done:
        return wait.result()
    wait.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await wait
    return None


class _Session:
    """One connected system: telemetry watchers, the tick loop, the dead-man, the stop."""

    def __init__(self, ctl: OffboardController, system):
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
        from mavsdk.asyncio.plugins.offboard import OffboardAsync
        from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

        self.ctl, self.system = ctl, system
        self.telemetry = TelemetryAsync(system)
        self.offboard = OffboardAsync(system)
        self.action = ActionAsync(system)
        self.direct = MavlinkDirectAsync(system)
        self.seen = _Telemetry()
        self.tasks: list[asyncio.Task] = []
        self.streaming = False
        self.last_tick_s = time.monotonic()
        self.deadman = _DeadMan(self)

    # -------------------------------------------------------------- watch the vehicle
    async def watch(self) -> None:
        from mavsdk.asyncio.plugins.telemetry import FlightMode

        async def follow(gen, apply):
            async for value in gen:
                apply(value)

        def on_mode(mode):
            self.seen.offboard = mode == FlightMode.OFFBOARD

        position: list = [None, 0]  # newest PositionVelocityNed, how many so far
        attitude: list = [None]

        def publish_pose() -> None:
            pv, att = position[0], attitude[0]
            if pv is None or att is None:
                return
            p = pv.position
            self.ctl.pose = VehiclePose(p.north_m, p.east_m, p.down_m, att.roll_deg,
                                        att.pitch_deg, att.yaw_deg, att.timestamp_us, position[1])

        def on_position(pv) -> None:
            position[0], position[1] = pv, position[1] + 1
            publish_pose()

        def on_attitude(att) -> None:
            attitude[0] = att
            publish_pose()

        self.tasks = [
            asyncio.ensure_future(follow(self.telemetry.subscribe_position_velocity_ned(),
                                         on_position)),
            asyncio.ensure_future(follow(self.telemetry.subscribe_attitude_euler(), on_attitude)),
            asyncio.ensure_future(follow(self.telemetry.subscribe_flight_mode(), on_mode)),
            asyncio.ensure_future(follow(self.telemetry.subscribe_armed(),
                                         lambda v: setattr(self.seen, "armed", bool(v)))),
            asyncio.ensure_future(follow(self.telemetry.subscribe_in_air(), self._on_in_air)),
        ]

    def _on_in_air(self, value) -> None:
        self.seen.in_air, self.seen.in_air_known = bool(value), True

    async def arm_and_take_off(self, stop: asyncio.Event) -> None:
        """Simulation only (``offboard.sim_arm_and_takeoff``): arm, take off, wait in air.

        A vehicle already in the air (a previous simulated run left it hovering) is left
        as it is."""
        from mavsdk.asyncio.plugins.action import ActionError

        cfg = self.ctl.config
        settle = time.monotonic() + 2.0  # the first EXTENDED_SYS_STATE arrives within ~1 s
        while not stop.is_set() and not self.seen.in_air_known and time.monotonic() < settle:
            await asyncio.sleep(0.05)
        if self.seen.in_air:
            self.ctl._event("simulation: already in the air")
            return
        self.ctl._event("simulation: arming and taking off")
        if cfg.offboard.sim_takeoff_altitude_m is not None:
            await self._call(self.action.set_takeoff_altitude(
                cfg.offboard.sim_takeoff_altitude_m), timeout_s=2.0)
        deadline = time.monotonic() + cfg.mavlink.connect_timeout_s + 20.0
        while not stop.is_set() and time.monotonic() < deadline:
            try:
                await self.action.arm()
                await self.action.takeoff()
                break
            except ActionError as exc:  # PX4 refuses arming until its estimator is ready
                log.info("arm/takeoff not yet accepted: %s", exc)
                await asyncio.sleep(0.5)
        while not stop.is_set() and not self.seen.in_air and time.monotonic() < deadline:
            await asyncio.sleep(0.1)

    # -------------------------------------------------------------- the tick loop
    async def supervise(self, stop: asyncio.Event) -> None:
        from mavsdk.asyncio.plugins.offboard import VelocityBodyYawspeed

        ctl, cfg = self.ctl, self.ctl.config
        period_s = 1.0 / cfg.offboard.setpoint_rate_hz
        report_every_s = 1.0 / cfg.offboard.eta_report_hz if cfg.offboard.eta_report_hz else 0
        next_report_s = 0.0
        od_every_s = (1.0 / cfg.mavlink.obstacle_distance_hz
                      if cfg.mavlink.obstacle_distance_hz else 0.0)
        next_od_s, last_od = 0.0, None
        self.deadman.start()
        wake = ctl._wake or asyncio.Event()
        relay = asyncio.ensure_future(stop.wait())
        relay.add_done_callback(lambda _: wake.set())
        self.tasks.append(relay)
        next_tick = time.monotonic()
        while not stop.is_set():
            wake.clear()  # a decision submitted from here on wakes the next tick
            now = ctl.clock()
            self.last_tick_s = time.monotonic()
            decision, enable = ctl._take()
            if enable:
                ctl.state = sv.enable(ctl.state)
                await self._announce("companion re-enabled")
            pose = ctl.pose
            vehicle = sv.VehicleStatus(
                connected=await self.system.is_connected(), armed=self.seen.armed,
                in_air=self.seen.in_air, offboard=self.seen.offboard,
                yaw_deg=None if pose is None else pose.yaw_deg)
            ctl.connected = vehicle.connected
            step = sv.supervise(ctl.state, vehicle, decision, now, cfg.offboard, cfg.policy)
            ctl.state = step.state
            for text in step.events:
                await self._announce(text)
            if step.stream:
                await self._call(self.offboard.set_velocity_body(VelocityBodyYawspeed(
                    step.forward_m_s, 0.0, 0.0, step.yaw_rate_deg_s)))
                if ctl.state.name == "active" and decision is not None:
                    ctl.sent = SentSetpoint(decision.t_s, time.monotonic(),
                                            step.forward_m_s, step.yaw_rate_deg_s)
            self.streaming = step.stream
            if step.request == "start":
                await self._command(_blocking(self.offboard).start, timeout_s=1.5)
            elif step.request == "stop":
                await self._command(_blocking(self.offboard).stop, timeout_s=1.5)
            elif step.request == "release":
                await self._release()
            ctl.ticked_t_s = None if decision is None else decision.t_s
            if (report_every_s and vehicle.connected and now >= next_report_s
                    and decision is not None and decision.eta_deg is not None):
                next_report_s = now + report_every_s
                await self._send("NAMED_VALUE_FLOAT", {
                    "time_boot_ms": int(now * 1000) & 0xFFFFFFFF, "name": "eta_deg",
                    "value": round(float(decision.eta_deg), 3)})
            wall = time.monotonic()
            if od_every_s and vehicle.connected and wall >= next_od_s:
                # On a fixed schedule (not "a period after the last one"), so that the
                # 20 Hz ticks make the rate exactly; after a stall, no burst.
                next_od_s = max(next_od_s + od_every_s, wall - od_every_s / 2)
                with ctl._lock:
                    measured = ctl._obstacle_distance
                fresh = (measured is not None and measured[1] is not None
                         and now - measured[0] <= cfg.offboard.stale_after_s)
                last_od = measured[1] if fresh else od.unknown(
                    last_od, cfg.mavlink.obstacle_distance_increment_deg)
                await self._send("OBSTACLE_DISTANCE",
                                 last_od.mavlink_fields(int(time.time() * 1e6)))
            # Ticks at setpoint_rate_hz, plus one at once for every new decision.
            wall = time.monotonic()
            if wall >= next_tick:
                next_tick += period_s
                if next_tick < wall - period_s:  # fell behind: don't burst
                    next_tick = wall
            delay = next_tick - wall
            turn_end = sv.turn_ends_at(decision, cfg.policy)
            if turn_end is not None and now < turn_end:
                # just past it, so the tick sees the turn done
                delay = min(delay, turn_end - ctl.clock() + 1e-4)
            delay = max(0.0, delay)
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(wake.wait(), timeout=delay)

    async def _release(self) -> None:
        """Stop streaming without touching the flight mode.

        MAVSDK's Offboard plugin resends its last setpoint until ``stop()``, and ``stop()``
        also commands Hold, which would undo a pilot's mode switch. Zero the setpoint
        (in case a resend slips out meanwhile), then drop the plugin instance, which ends
        its resending, and start a fresh one for a later engagement.
        """
        from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityBodyYawspeed

        await self._call(self.offboard.set_velocity_body(
            VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0)), timeout_s=0.1)
        self.streaming = False
        old, self.offboard = self.offboard, OffboardAsync(self.system)
        old.destroy()

    # -------------------------------------------------------------- the safe stop
    async def close(self) -> None:
        """Zero yaw rate, then Hold if offboard was engaged; bounded by STOP_BUDGET_S."""
        from mavsdk.asyncio.plugins.offboard import VelocityBodyYawspeed

        self.deadman.stop()
        engaged = self.ctl.state.name in ("engaging", "active")
        if engaged or self.streaming:
            await self._call(self.offboard.set_velocity_body(
                VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0)), timeout_s=0.1)
        if engaged:
            self.ctl.state = sv.SupervisorState("disabled", False)
            await self._announce("companion stopping: yaw rate 0, Hold")
            await self._command(_blocking(self.offboard).stop, timeout_s=STOP_BUDGET_S)
        for task in self.tasks:
            task.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)

    # -------------------------------------------------------------- MAVLink out
    async def _announce(self, text: str) -> None:
        """A state change: logged, and a STATUSTEXT for QGroundControl."""
        self.ctl._event(text)
        await self._send("STATUSTEXT", {"severity": 6, "text": f"companion: {text}"[:50],
                                        "id": 0, "chunk_seq": 0})

    async def _send(self, name: str, fields: dict) -> None:
        """One MAVLink message through MAVSDK's MavlinkDirect (fields by MAVLink name)."""
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkMessage

        msg = MavlinkMessage(name, COMPANION_SYSTEM_ID, COMPANION_COMPONENT_ID, 0, 0,
                             json.dumps(fields, allow_nan=True))
        await self._call(self.direct.send_message(msg), timeout_s=0.2)

    async def _command(self, blocking_call, timeout_s: float) -> None:
        """A MAVSDK call that waits for a COMMAND_ACK (offboard start/stop), bounded.

        It runs on a daemon thread of its own rather than the loop's executor: with the
        link gone MAVSDK can block in it past our timeout, and an executor thread would
        then hold up the process's exit, breaking the 1 s SIGTERM promise.
        """
        from mavsdk.asyncio import MavsdkError

        done = threading.Event()

        def run() -> None:
            try:
                blocking_call()
            except MavsdkError as exc:
                log.info("MAVSDK command failed: %s", exc)
            finally:
                done.set()

        threading.Thread(target=run, name="mavsdk-command", daemon=True).start()
        deadline = time.monotonic() + timeout_s
        while not done.is_set() and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
        if not done.is_set():
            log.info("MAVSDK command still unanswered after %.1f s; moving on", timeout_s)

    async def _call(self, coro, timeout_s: float = 0.5):
        """Await a MAVSDK call; a failure is logged, never fatal to the loop."""
        from mavsdk.asyncio import MavsdkError

        try:
            return await asyncio.wait_for(coro, timeout=timeout_s)
        except (TimeoutError, MavsdkError) as exc:
            log.info("MAVSDK call failed: %s", exc.__class__.__name__ + f" {exc}".rstrip())
            return None


def _blocking(offboard):
    """The synchronous Offboard plugin underneath an ``OffboardAsync``.

    Its blocking calls are made from threads we own: ``start``/``stop`` wait for a
    COMMAND_ACK that a lost link may never bring (see ``_Session._command``), and the
    dead-man must zero the setpoint while the asyncio loop is stalled. MAVSDK 4 exposes
    it only as ``_plugin``; the SITL tests exercise every use, so a MAVSDK release that
    renames it fails CI rather than a flight.
    """
    return offboard._plugin


class _DeadMan:
    """Zero the setpoint from a plain thread if the asyncio loop stops ticking.

    MAVSDK keeps resending the last setpoint on its own thread; this makes sure that what
    it resends is 0 when nothing is supervising it.
    """

    def __init__(self, session: _Session):
        self.session = session
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="offboard-deadman", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=0.5)

    def _run(self) -> None:
        from mavsdk.asyncio import MavsdkError
        from mavsdk.plugins.offboard import VelocityBodyYawspeed

        s = self.session
        limit_s = s.ctl.config.offboard.stale_after_s
        tripped = False
        while not self._stop.wait(limit_s / 4):
            stalled = time.monotonic() - s.last_tick_s > limit_s
            if stalled and s.streaming and not tripped:
                log.warning("control loop stalled for > %.2f s: yaw rate 0", limit_s)
                # The loop is not running: the blocking call, from this thread.
                with contextlib.suppress(MavsdkError):
                    _blocking(s.offboard).set_velocity_body(
                        VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0))
            tripped = stalled


def run_until_signal(controller: OffboardController) -> int:
    """Run ``controller`` until SIGINT/SIGTERM; the safe stop runs before returning 0.

    Returns 3 with a one-line message if no autopilot answers.
    """

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await controller.run(stop)

    try:
        asyncio.run(main())
    except AutopilotNotFound as exc:
        log.error("%s", exc)
        return 3
    return 0
