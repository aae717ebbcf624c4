"""The mock autopilot alone, driven by a plain pymavlink client over loopback UDP.

These pin down the PX4 behaviour the MAVSDK integration tests rely on (PX4-NOTES.md):
mode encoding, truthful acks, the offboard entry and loss rules, robustness to junk.
"""

import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot import HOLD, OFFBOARD, POSCTL, RTL, AutopilotParams, MockAutopilot, Px4Mode


def start(client, **params) -> MockAutopilot:
    ap = MockAutopilot(client.port, AutopilotParams(**params)).start()
    assert client.recv("HEARTBEAT") is not None, "the mock must send to 127.0.0.1:PORT"
    return ap


def test_heartbeat_is_a_px4_quadrotor_with_mode_and_armed_flag(client):
    with start(client, boot_in_air=True):
        hb = client.recv("HEARTBEAT")
        assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
        assert hb.type == mavlink.MAV_TYPE_QUADROTOR
        assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
        assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        assert Px4Mode.from_custom_mode(hb.custom_mode) == HOLD
        assert hb.custom_mode == (4 << 16) | (3 << 24)


def test_commands_get_truthful_acks(client):
    with start(client, arm_ready_s=0.6) as ap:
        assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == \
            mavlink.MAV_RESULT_TEMPORARILY_REJECTED  # estimator not ready yet
        assert client.command(mavlink.MAV_CMD_NAV_TAKEOFF) == mavlink.MAV_RESULT_DENIED
        time.sleep(0.7)
        assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == \
            mavlink.MAV_RESULT_ACCEPTED
        assert ap.vehicle.armed
        assert client.command(31999) == mavlink.MAV_RESULT_UNSUPPORTED
        assert client.command(mavlink.MAV_CMD_REQUEST_MESSAGE,
                              mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == 0
        version = client.recv("AUTOPILOT_VERSION")
        assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2


def test_offboard_needs_a_setpoint_stream_in_the_air(client):
    with start(client, boot_in_air=True) as ap:
        # As PX4 does: accepted, but the mode does not change.
        assert client.set_mode(OFFBOARD) == mavlink.MAV_RESULT_ACCEPTED
        time.sleep(0.3)
        assert ap.mode == HOLD
        for _ in range(3):
            client.setpoint()
            time.sleep(0.1)
        assert client.set_mode(OFFBOARD) == mavlink.MAV_RESULT_ACCEPTED
        assert ap.wait_for(lambda: ap.mode == OFFBOARD, 0.5)


def test_setpoint_loss_fails_safe_after_com_of_loss_t(client):
    with start(client, boot_in_air=True, com_of_loss_t_s=0.6) as ap:
        client.setpoint(0.5)
        time.sleep(0.05)
        client.setpoint(0.5)
        assert client.set_mode(OFFBOARD) == 0
        t_last = time.monotonic()
        client.setpoint(0.5)
        assert ap.wait_for(lambda: ap.mode != OFFBOARD, 2.0)
        lost_after = ap.mode_changes[-1][0] - t_last
        assert ap.mode == RTL
        assert 0.55 <= lost_after <= 0.9
        assert client.recv("STATUSTEXT", 1.0) is not None


def test_body_yaw_rate_turns_the_vehicle_and_every_setpoint_is_recorded(client):
    with start(client, boot_in_air=True) as ap:
        client.setpoint(0.0)
        assert client.set_mode(OFFBOARD) == 0
        y0, t0 = ap.yaw_deg, time.monotonic()
        while time.monotonic() - t0 < 1.5:
            client.setpoint(-0.349066)  # -20 deg/s: turn left
            time.sleep(0.05)
        turned = ap.yaw_deg - y0
        # As PX4 (PX4-NOTES.md): 0.25 s dead time, then a steady 18-19.5 deg/s.
        assert -24.0 < turned < -18.0
        recorded = ap.setpoints_since(t0)
        assert len(recorded) >= 25
        assert all(s.frame == mavlink.MAV_FRAME_BODY_NED and s.type_mask == 1479
                   for s in recorded)
        assert recorded[-1].yaw_rate_deg_s == pytest.approx(-20.0, abs=0.01)


def test_pilot_switch_wins_over_offboard(client):
    with start(client, boot_in_air=True) as ap:
        client.setpoint()
        assert client.set_mode(OFFBOARD) == 0
        ap.pilot_set_mode(POSCTL)
        hb = client.recv("HEARTBEAT", 1.5, where=lambda m: m.custom_mode == POSCTL.custom_mode)
        assert hb is not None


def test_junk_and_wrong_targets_are_ignored_without_crashing(client):
    with start(client, boot_in_air=True) as ap:
        client.recv("HEARTBEAT")
        client.sock.sendto(b"\xfd\x09garbage that is not mavlink" * 4, client.peer)
        client.sock.sendto(b"", client.peer)
        assert client.command(mavlink.MAV_CMD_NAV_LAND, target=(7, 1)) is None
        assert client.command(mavlink.MAV_CMD_NAV_LAND, target=(1, 99)) is None
        assert ap.mode == HOLD
        # still alive and answering
        assert client.command(mavlink.MAV_CMD_NAV_LAND) == mavlink.MAV_RESULT_ACCEPTED
        assert ap.wait_for(lambda: ap.mode.sub == 6, 0.5)


def test_a_free_port_for_a_listener_is_never_one_a_port_0_bind_could_be_handed():
    """free_udp_port reserves by number only; a socket bound to port 0 before the listener
    binds must not be able to take it, so it comes from outside the ephemeral range."""
    from sitl.autopilot import _ephemeral_port_range, free_udp_port

    low, high = _ephemeral_port_range()
    taken = []
    for _ in range(50):
        port = free_udp_port()
        assert not low <= port <= high
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", port))  # free, as promised
        taken.append(port)
    assert len(set(taken)) > 40  # drawn, not one fixed port
