"""Integration: the real MAVSDK (libcmavsdk) ↔ the mock PX4, over loopback UDP.

Each test gets its own free port, so the suite can run in parallel. Every wait is bounded.
Timings the assertions allow for: the mock's heartbeat (and so MAVSDK's flight mode) comes
at 1 Hz, as PX4's does.
"""

import asyncio
import os
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest
from helpers.processes import free_udp_port, stop_with_sigterm

from companion.config import Config, MavlinkConfig, PolicyConfig
from companion.control.offboard import OffboardController
from companion.control.policy import TurnCommand
from sitl.autopilot import HOLD, OFFBOARD, POSCTL, AutopilotParams, MockAutopilot
from sitl.closed_loop import hovering_autopilot, sitl_link

ROOT = Path(__file__).resolve().parents[1]


def in_air_autopilot(port: int, **params) -> MockAutopilot:
    return hovering_autopilot(port, **params).start()


def fly_config(port: int, policy: PolicyConfig | None = None, **offboard) -> Config:
    """Hovering (forward speed 0: Table II per decision) unless ``offboard`` says otherwise."""
    return sitl_link(Config(policy=policy or PolicyConfig()), port,
                     **{"forward_speed_m_s": 0.0, **offboard})


class Running:
    """The controller's asyncio session in a thread of its own, stoppable from the test."""

    def __init__(self, config: Config):
        self.controller = OffboardController(config)
        self.loop = asyncio.new_event_loop()
        self.stop_event = asyncio.Event()
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        try:
            self.loop.run_until_complete(self.controller.run(self.stop_event))
        except BaseException as exc:  # surfaced by stop()
            self.error = exc

    def __enter__(self) -> "Running":
        self.thread.start()
        return self

    def stop(self) -> float:
        t0 = time.monotonic()
        if self.thread.is_alive():
            self.loop.call_soon_threadsafe(self.stop_event.set)
            self.thread.join(timeout=5)
        assert not self.thread.is_alive(), "controller did not stop"
        if self.error is not None:
            raise self.error
        return time.monotonic() - t0

    def __exit__(self, *exc) -> None:
        self.stop()

    def block_loop(self, seconds: float) -> None:
        """Freeze the controller's event loop, as a hung call would."""
        self.loop.call_soon_threadsafe(time.sleep, seconds)


class Camera:
    """Stands in for the vision thread: submits ``command`` at 15 Hz until stopped."""

    def __init__(self, controller: OffboardController, command: TurnCommand, eta_deg=None):
        self.controller, self.command, self.eta_deg = controller, command, eta_deg
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.controller.submit(self.command, self.eta_deg)
            self._stop.wait(1 / 15)

    def __enter__(self) -> "Camera":
        self.thread.start()
        return self

    def stop(self) -> float:
        self._stop.set()
        self.thread.join(timeout=1)
        return time.monotonic()

    def __exit__(self, *exc) -> None:
        self.stop()


RIGHT_20 = TurnCommand("right", 20.0, 20.0)
FORWARD = TurnCommand("forward", 0.0, 0.0)


def wait_offboard(ap: MockAutopilot, timeout_s: float = 8.0) -> None:
    assert ap.wait_for(lambda: ap.mode == OFFBOARD, timeout_s), \
        f"offboard not engaged; mode {ap.mode.name}"


def wait_active(ap: MockAutopilot, run: Running, timeout_s: float = 8.0) -> None:
    """OFFBOARD in the mock, and seen in a heartbeat by the controller (up to 1 s later)."""
    wait_offboard(ap, timeout_s)
    assert ap.wait_for(lambda: run.controller.state.name == "active", 2.0)


@pytest.fixture
def port() -> int:
    return free_udp_port()


def test_mavsdk_discovers_the_mock_as_a_px4_quadrotor(port):
    from mavsdk.asyncio import Autopilot, ComponentType, Configuration, Mavsdk, Vehicle
    from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

    async def discover():
        config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        async with Mavsdk(config) as mavsdk:
            await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
            system = await mavsdk.first_autopilot(timeout_s=5.0)
            assert system is not None
            telemetry = TelemetryAsync(system)
            mode = await asyncio.wait_for(anext(telemetry.subscribe_flight_mode()), 3)
            return (await system.autopilot_type(), await system.vehicle_type(), mode,
                    await telemetry.armed())

    with in_air_autopilot(port) as ap:
        autopilot, vehicle, mode, armed = asyncio.run(discover())
    assert autopilot == Autopilot.PX4
    assert vehicle == Vehicle.MULTICOPTER
    assert mode == FlightMode.HOLD and armed
    assert any(cmd == 512 and result == 0 for _, cmd, result in ap.acks), \
        "AUTOPILOT_VERSION must be requested and answered"


def test_offboard_is_refused_without_a_setpoint_stream_and_entered_with_one(port):
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync, MavlinkMessage
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityBodyYawspeed

    async def session(ap):
        config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        async with Mavsdk(config) as mavsdk:
            await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
            system = await mavsdk.first_autopilot(timeout_s=5.0)
            # DO_SET_MODE OFFBOARD with no setpoints sent: PX4 acks it and stays put.
            ack = await MavlinkDirectAsync(system).send_command(MavlinkMessage(
                "COMMAND_LONG", 1, 195, 1, 1,
                '{"target_system":1,"target_component":1,"command":176,"confirmation":0,'
                '"param1":1,"param2":6,"param3":0,"param4":0,"param5":0,"param6":0,'
                '"param7":0}'))
            await asyncio.sleep(1.0)
            mode_without_stream = ap.mode
            offboard = OffboardAsync(system)
            await offboard.set_velocity_body(VelocityBodyYawspeed(0, 0, 0, 0))
            await offboard.start()
            entered = ap.wait_for(lambda: ap.mode == OFFBOARD, 2.0)
            await offboard.stop()
            return ack, mode_without_stream, entered

    with in_air_autopilot(port) as ap:
        ack, mode_without_stream, entered = asyncio.run(session(ap))
    assert '"result":0' in ack.fields_json.replace(" ", "")
    assert mode_without_stream == HOLD
    assert entered


@pytest.mark.parametrize("sign", [1, -1])
def test_yaw_rate_turns_the_vehicle_with_the_right_sign_and_magnitude(port, sign):
    command = TurnCommand("right" if sign > 0 else "left", 20.0 * sign, 20.0 * sign)
    with in_air_autopilot(port) as ap, Running(fly_config(port)) as run, \
            Camera(run.controller, command, eta_deg=25.0 * sign):
        wait_active(ap, run)
        time.sleep(0.5)  # past the first-order lag
        y0, t0 = ap.yaw_deg, time.monotonic()
        time.sleep(2.0)
        turned = (ap.yaw_deg - y0 + 180) % 360 - 180
        sent = ap.setpoints_since(t0)
    assert turned == pytest.approx(40.0 * sign, abs=4.0)
    assert all(s.frame == 8 and s.type_mask == 1479 for s in sent)  # BODY_NED, vel + yaw rate
    assert {round(s.yaw_rate_deg_s, 3) for s in sent} == {20.0 * sign}
    assert len(sent) >= 2.0 * 20 * 0.9  # at least the configured 20 Hz
    assert any(name == "eta_deg" and value == 25.0 * sign for _, name, value in ap.named_values)
    assert any("offboard engaged" in text for _, _, text in ap.statustexts)


def test_one_decision_never_turns_more_than_the_cap(port):
    policy = PolicyConfig(max_turn_deg=30.0, max_yaw_rate_deg_s=30.0)
    config = fly_config(port, policy, stale_after_s=5.0, hold_after_s=10.0)
    with in_air_autopilot(port) as ap, Running(config) as run:
        with Camera(run.controller, FORWARD):
            wait_active(ap, run)
        y0, t0 = ap.yaw_deg, time.monotonic()
        run.controller.submit(TurnCommand("right", 80.0, 80.0), 80.0)  # beyond both caps
        time.sleep(3.0)
        turned = ap.yaw_deg - y0
        sent = ap.setpoints_since(t0)
    assert max(s.yaw_rate_deg_s for s in sent) == pytest.approx(30.0, abs=0.01)
    assert 26.0 <= turned <= 31.0
    assert sent[-1].yaw_rate_deg_s == 0.0


def test_vision_stall_zeroes_the_yaw_rate_at_once_then_holds(port):
    config = fly_config(port, stale_after_s=0.5, hold_after_s=2.0)
    with in_air_autopilot(port) as ap, Running(config) as run:
        with Camera(run.controller, RIGHT_20) as camera:
            wait_active(ap, run)
            time.sleep(0.5)
            t_stall = camera.stop()
        assert ap.wait_for(lambda: ap.mode == HOLD, 4.0)
        t_hold = ap.mode_changes[-1][0]
        sent = ap.setpoints_since(t_stall)
    turning = [s.t_s - t_stall for s in sent if s.yaw_rate_deg_s != 0.0]
    assert max(turning, default=0.0) <= 0.5 + 0.15  # zero within stale_after_s (+ a tick)
    assert any(s.yaw_rate_deg_s == 0.0 and s.mode == "OFFBOARD" for s in sent)
    assert 2.0 - 0.1 <= t_hold - t_stall <= 2.0 + 0.5
    texts = [text for _, _, text in ap.statustexts]
    assert any("vision stalled: stop, yaw rate 0" in t for t in texts)
    assert any("vision stalled: Hold" in t for t in texts)
    assert run.controller.state.name == "disabled"


def test_pilot_override_wins_and_is_not_undone_until_re_enabled(port):
    with in_air_autopilot(port) as ap, Running(fly_config(port)) as run, \
            Camera(run.controller, RIGHT_20):
        wait_active(ap, run)
        t_pilot = time.monotonic()
        ap.pilot_set_mode(POSCTL)
        time.sleep(3.0)  # vision keeps deciding turns all along
        assert ap.mode == POSCTL  # the companion did not fight the pilot
        # MAVSDK sees the mode in the next 1 Hz heartbeat; nothing after that.
        assert ap.setpoints_since(t_pilot + 1.3) == []
        assert run.controller.state.name == "disabled"
        assert any("offboard left by pilot" in text for _, _, text in ap.statustexts)
        run.controller.enable()
        wait_offboard(ap)


def test_link_loss_then_a_restarted_autopilot_is_reconnected_without_resuming(port):
    with Running(fly_config(port)) as run, Camera(run.controller, RIGHT_20):
        with in_air_autopilot(port) as first:
            wait_active(first, run)
        deadline = time.monotonic() + 10
        while run.controller.state.name != "link_lost" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert run.controller.state.name == "link_lost"
        with in_air_autopilot(port) as second:
            assert second.wait_for(lambda: "autopilot link restored" in " ".join(
                run.controller.events), 10.0)
            time.sleep(2.0)
            assert second.mode == HOLD
            assert second.setpoints == []  # not one setpoint: no silent resume
            assert run.controller.state.name == "disabled"
            run.controller.enable()
            wait_offboard(second)


def test_a_stalled_control_loop_leaves_zero_not_the_last_turn(port):
    config = fly_config(port, stale_after_s=0.4)
    with in_air_autopilot(port) as ap, Running(config) as run, \
            Camera(run.controller, RIGHT_20):
        wait_active(ap, run)
        time.sleep(0.3)
        t_block = time.monotonic()
        run.block_loop(2.0)  # MAVSDK's own thread keeps resending meanwhile
        time.sleep(1.8)
        resent = [s for s in ap.setpoints_since(t_block + 0.4 + 0.2)
                  if s.t_s < t_block + 1.8]
    assert len(resent) >= 10
    assert all(s.yaw_rate_deg_s == 0.0 for s in resent)


def test_sigterm_stops_turning_releases_offboard_and_exits_within_a_second(port):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with in_air_autopilot(port) as ap:
        proc = subprocess.Popen(
            [sys.executable, str(ROOT / "tests" / "helpers" / "fly_constant.py"), str(port),
             "15"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            wait_offboard(ap, 15.0)
            time.sleep(0.5)
        finally:
            code, took = stop_with_sigterm(proc)
        output = proc.stdout.read()
        assert ap.wait_for(lambda: ap.mode == HOLD, 0.5)
        last = ap.setpoints[-1]
    assert code == 0, output
    assert took < 1.0, f"exit took {took:.2f} s"
    assert last.yaw_rate_deg_s == 0.0
    assert "Traceback" not in output


def test_no_autopilot_gives_one_clear_error(port):
    from companion.control.offboard import AutopilotNotFound

    run = Running(replace(fly_config(port), mavlink=MavlinkConfig(
        url=f"udpin://127.0.0.1:{port}", connect_timeout_s=0.5)))
    message = f"no autopilot answered on udpin://127.0.0.1:{port} within 0.5 s"
    with pytest.raises(AutopilotNotFound, match=message), run:
        run.thread.join(timeout=5)


def test_simulation_only_arm_and_takeoff_waits_for_px4_then_engages(port):
    ap = MockAutopilot(port, AutopilotParams(arm_ready_s=1.5, climb_rate_m_s=2.5)).start()
    with ap, Running(fly_config(port, sim_arm_and_takeoff=True)) as run, \
            Camera(run.controller, FORWARD):
        wait_active(ap, run, timeout_s=12.0)
        assert ap.vehicle.armed and ap.vehicle.in_air
    rejected = [r for _, cmd, r in ap.acks if cmd == 400 and r == 1]
    assert rejected, "arming before the mock was ready must have been refused and retried"


def test_a_new_decision_goes_out_at_once_not_at_the_next_tick(port):
    # Ticks every 0.4 s: a setpoint that waited for the tick would arrive ~0.2 s late on average.
    config = fly_config(port, setpoint_rate_hz=2.5, stale_after_s=5.0, hold_after_s=10.0)
    delays = []
    with in_air_autopilot(port) as ap, Running(config) as run:
        with Camera(run.controller, FORWARD):
            wait_active(ap, run)
        for k in range(6):
            rate = 5.0 + k
            t0 = time.monotonic()
            run.controller.submit(TurnCommand("right", rate, rate), rate)
            assert ap.wait_for(lambda r=rate, t0=t0: any(
                abs(s.yaw_rate_deg_s - r) < 1e-3 for s in ap.setpoints_since(t0)), 1.0)
            first = next(s for s in ap.setpoints_since(t0) if abs(s.yaw_rate_deg_s - rate) < 1e-3)
            delays.append(first.t_s - t0)
            time.sleep(0.13 * (k % 3))  # land at different phases of the tick
    assert max(delays) < 0.1, delays


def test_forward_flight_streams_the_ramped_speed_and_stops_at_once_when_vision_stalls(port):
    config = fly_config(port, forward_speed_m_s=0.8, forward_accel_m_s2=0.8, stale_after_s=0.5)
    with in_air_autopilot(port) as ap, Running(config) as run:
        camera = Camera(run.controller, FORWARD)
        with camera:
            wait_active(ap, run)
            t_active = time.monotonic()
            time.sleep(2.0)
            north0 = ap.vehicle.motion.north_m
            time.sleep(1.0)
            moved = ap.vehicle.motion.north_m - north0  # boot heading 0: forward is north
            t_stall = camera.stop()
        time.sleep(1.0)
        sent = ap.setpoints_since(t_active)
    speeds = [(s.t_s, s.vx_m_s) for s in sent]
    assert all(s.vz_m_s == 0.0 and s.type_mask == 1479 for s in sent)  # altitude is PX4's
    ramp = [v for t, v in speeds if t < t_stall]
    assert ramp[0] <= 0.8 * 0.1 + 0.05  # no jump at the start ...
    assert max(ramp) == pytest.approx(0.8)  # ... up to the configured speed
    assert all(b >= a - 1e-9 for a, b in zip(ramp, ramp[1:], strict=False))
    assert 0.4 < moved < 0.9  # the vehicle flew forward, PX4's lag included
    after = [(t - t_stall, v) for t, v in speeds if t > t_stall + 0.5 + 0.1]
    assert after and all(v == 0.0 for _, v in after)  # stale vision: stopped
