"""The mock autopilot flies like PX4 (PX4-NOTES.md): the response model on values, then the
mock in lock-step, driven by a plain pymavlink client over loopback UDP."""

import math

import pytest

from sitl.autopilot import OFFBOARD, RTL, AutopilotParams, MockAutopilot
from sitl.multicopter import Motion, Response, step

R = Response()


def fly_step(cmd_ned, yaw_rate, seconds, motion=None, dt=0.01):
    """``motion`` after ``seconds`` of the command (no dead time: the mock adds that)."""
    m = motion or Motion()
    for _ in range(round(seconds / dt)):
        step(m, cmd_ned, yaw_rate, dt, R)
    return m


def test_velocity_step_rises_like_px4():
    # PX4 SIH, 1 m/s forward: 0.57 m/s after 1 s, 0.76 after 2 s, 0.9 only after ~4 s,
    # counted from the command, ~0.3 s of it dead time.
    speeds = {t: fly_step((1.0, 0.0, 0.0), 0.0, t - R.velocity_dead_s).velocity(R)[0]
              for t in (1.0, 2.0, 4.0)}
    assert 0.5 <= speeds[1.0] <= 0.65
    assert 0.7 <= speeds[2.0] <= 0.85
    assert 0.85 <= speeds[4.0] <= 0.95


def test_yaw_rate_step_settles_at_px4s_steady_rate():
    m = fly_step((0.0, 0.0, 0.0), 20.0, 0.6 - R.yaw_dead_s)
    assert m.yaw_rate_deg_s >= 15.0  # ~17 deg/s 0.6 s after the command
    m = fly_step((0.0, 0.0, 0.0), 20.0, 2.0, m)
    assert 18.0 <= m.yaw_rate_deg_s <= 19.5


def test_the_body_tilts_into_the_acceleration():
    speeding_up = fly_step((1.0, 0.0, 0.0), 0.0, 0.3)  # heading north, speeding north
    assert speeding_up.pitch_deg < -2.0 and abs(speeding_up.roll_deg) < 0.1
    cruising = fly_step((1.0, 0.0, 0.0), 0.0, 20.0)
    assert abs(cruising.pitch_deg) < 0.2
    east = Motion(yaw_deg=0.0)  # heading north, pushed east: to the right, roll right
    assert fly_step((0.0, 1.0, 0.0), 0.0, 0.3, east).roll_deg > 2.0


def test_lockstep_moves_only_when_advanced_and_flies_the_body_frame(client):
    ap = MockAutopilot(client.port, AutopilotParams(
        lockstep=True, boot_in_air=True, arm_ready_s=0.0, boot_yaw_deg=90.0)).start()
    try:
        assert client.recv("HEARTBEAT") is not None  # the link runs on real time
        client.setpoint(forward_m_s=1.0)
        assert client.set_mode(OFFBOARD) == 0 and ap.mode == OFFBOARD
        before = ap.vehicle.motion.north_m, ap.vehicle.motion.east_m
        client.recv("NOTHING", timeout_s=0.3)  # real time passes ...
        assert (ap.vehicle.motion.north_m, ap.vehicle.motion.east_m) == before  # ... no motion
        for _ in range(30):  # 3 s of simulated time, heading east
            client.setpoint(forward_m_s=1.0)
            client.recv("NOTHING", timeout_s=0.005)
            t = ap.advance(0.1)
        m = ap.vehicle.motion
        assert t == pytest.approx(3.0)
        assert 1.5 < m.east_m < 2.5 and abs(m.north_m) < 0.05  # forward is east at 90°
        # The pose goes out with every step, stamped with the simulated clock.
        client.sock.settimeout(0.05)
        pose = []
        while len(pose) < 2:
            data, _ = client.sock.recvfrom(65535)
            pose += [msg for msg in client.parser.parse_buffer(data) or []
                     if msg.get_type() in ("LOCAL_POSITION_NED", "ATTITUDE")]
        ap.advance(0.1)
        latest = {}
        while True:
            try:
                data, _ = client.sock.recvfrom(65535)
            except TimeoutError:
                break
            for msg in client.parser.parse_buffer(data) or []:
                latest[msg.get_type()] = msg
        assert latest["ATTITUDE"].time_boot_ms == pytest.approx(3100, abs=1)
        assert math.degrees(latest["ATTITUDE"].yaw) == pytest.approx(90.0, abs=0.5)
        assert latest["LOCAL_POSITION_NED"].y == pytest.approx(ap.vehicle.motion.east_m)
        assert latest["LOCAL_POSITION_NED"].vy > 0.8
    finally:
        ap.stop()


def test_lockstep_failsafe_runs_on_simulated_time(client):
    ap = MockAutopilot(client.port, AutopilotParams(
        lockstep=True, boot_in_air=True, arm_ready_s=0.0)).start()
    try:
        assert client.recv("HEARTBEAT") is not None
        client.setpoint(forward_m_s=0.5)
        assert client.set_mode(OFFBOARD) == 0
        client.recv("NOTHING", timeout_s=1.5)  # 1.5 s of real time without setpoints ...
        assert ap.mode == OFFBOARD  # ... is no simulated time at all
        ap.advance(0.9)
        assert ap.mode == OFFBOARD
        ap.advance(0.2)  # 1.1 s of simulated time since the last setpoint: COM_OF_LOSS_T
        assert ap.mode == RTL
    finally:
        ap.stop()


def test_advance_needs_lockstep(client):
    with MockAutopilot(client.port) as ap, pytest.raises(RuntimeError):
        ap.advance(0.1)
