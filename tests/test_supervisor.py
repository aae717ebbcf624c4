"""The offboard state machine and the yaw-rate budget, on values alone (no MAVSDK)."""

import math
from dataclasses import replace

import pytest

from companion.config import OffboardConfig, PolicyConfig
from companion.control.policy import TurnCommand
from companion.control.supervisor import (
    Decision,
    SupervisorState,
    VehicleStatus,
    enable,
    initial_state,
    supervise,
    turn_ends_at,
    yaw_rate_setpoint,
)

CFG = OffboardConfig(enabled=True, stale_after_s=0.5, hold_after_s=3.0, confirm_timeout_s=3.0,
                     retry_after_s=5.0)
POLICY = PolicyConfig(max_turn_deg=30.0, max_yaw_rate_deg_s=30.0, slow_within_m=2.0,
                      stop_within_m=0.8)
FLYING = VehicleStatus(connected=True, armed=True, in_air=True)
IN_OFFBOARD = VehicleStatus(connected=True, armed=True, in_air=True, offboard=True)
RIGHT = TurnCommand("right", 20.0, 20.0)


def run(state, vehicle, decision, now):
    return supervise(state, vehicle, decision, now, CFG, POLICY)


def active_state():
    return SupervisorState("active", True, vision_fresh=True, start_t_s=0.0)


def test_disabled_by_default_and_never_streams():
    state = initial_state(OffboardConfig())
    step = run(state, IN_OFFBOARD, Decision(10.0, RIGHT), 10.0)
    assert step.state.name == "disabled" and not step.stream and step.request is None


def test_engages_only_armed_in_air_with_fresh_vision():
    state = initial_state(CFG)
    assert run(state, VehicleStatus(True, armed=True), Decision(1.0, RIGHT), 1.0).request is None
    assert run(state, FLYING, None, 1.0).request is None
    assert run(state, FLYING, Decision(0.0, RIGHT), 1.0).request is None  # stale
    step = run(state, FLYING, Decision(1.0, RIGHT), 1.0)
    assert step.request == "start" and step.state.name == "engaging"
    assert step.stream and step.yaw_rate_deg_s == 0.0  # zero before OFFBOARD is confirmed


def test_confirmed_only_by_the_heartbeat_then_turns():
    engaging = run(initial_state(CFG), FLYING, Decision(1.0, RIGHT), 1.0).state
    still = run(engaging, FLYING, Decision(1.5, RIGHT), 1.5)
    assert still.state.name == "engaging" and still.yaw_rate_deg_s == 0.0
    active = run(engaging, IN_OFFBOARD, Decision(1.5, RIGHT), 1.5)
    assert active.state.name == "active" and active.yaw_rate_deg_s == 20.0
    assert "offboard engaged" in active.events
    timeout = run(engaging, FLYING, Decision(4.5, RIGHT), 4.5)
    assert timeout.state.name == "waiting" and timeout.request == "release"
    retry_too_soon = run(timeout.state, FLYING, Decision(5.0, RIGHT), 5.0)
    assert retry_too_soon.request is None
    assert run(timeout.state, FLYING, Decision(6.0, RIGHT), 6.0).request == "start"


def test_pilot_leaving_offboard_releases_without_a_mode_command_and_latches():
    step = run(active_state(), FLYING, Decision(2.0, RIGHT), 2.0)
    assert step.state.name == "disabled" and not step.state.enabled
    assert step.request == "release" and not step.stream
    again = run(step.state, FLYING, Decision(9.0, RIGHT), 9.0)
    assert again.state.name == "disabled" and again.request is None
    rearmed = enable(again.state)
    assert run(rearmed, FLYING, Decision(9.0, RIGHT), 9.0).request == "start"


def test_vision_stall_zero_first_then_hold():
    decision = Decision(1.0, RIGHT)
    assert run(active_state(), IN_OFFBOARD, decision, 1.2).yaw_rate_deg_s == 20.0
    stalled = run(active_state(), IN_OFFBOARD, decision, 1.6)
    assert stalled.stream and stalled.yaw_rate_deg_s == 0.0 and stalled.request is None
    assert "vision stalled: stop, yaw rate 0" in stalled.events
    held = run(stalled.state, IN_OFFBOARD, decision, 4.1)
    assert held.request == "stop" and held.state.name == "disabled"


def test_link_loss_never_resumes_silently():
    lost = run(active_state(), VehicleStatus(connected=False), Decision(2.0, RIGHT), 2.0)
    assert lost.state.name == "link_lost" and lost.request == "release" and not lost.stream
    back = run(lost.state, FLYING, Decision(3.0, RIGHT), 3.0)
    assert back.state.name == "disabled" and back.request is None
    # Not engaged when the link dropped: nothing to latch.
    idle_lost = run(initial_state(CFG), VehicleStatus(connected=False), None, 1.0)
    assert run(idle_lost.state, FLYING, None, 2.0).state.name == "waiting"


@pytest.mark.parametrize(("age_s", "expected"), [(0.0, 20.0), (0.4, 20.0), (0.6, 0.0)])
def test_yaw_rate_zero_when_the_decision_is_stale(age_s, expected):
    assert yaw_rate_setpoint(Decision(10.0, RIGHT), 10.0 + age_s, 0.5, POLICY) == expected


def test_one_decision_turns_at_most_the_cap():
    huge = Decision(0.0, TurnCommand("left", -90.0, -90.0))
    long_lived = 100.0
    rates = [yaw_rate_setpoint(huge, t / 100, long_lived, POLICY) for t in range(300)]
    assert min(rates) == -30.0  # rate capped
    assert sum(rates) / 100 == pytest.approx(-30.0, abs=0.31)  # turn capped at 30°
    assert rates[-1] == 0.0


def test_the_turn_ends_where_the_setpoint_drops_to_zero():
    huge = Decision(2.0, TurnCommand("left", -90.0, -90.0))
    end = turn_ends_at(huge, POLICY)
    assert end == pytest.approx(3.0)  # 30° cap at the 30°/s cap
    assert yaw_rate_setpoint(huge, end - 1e-3, 100.0, POLICY) == -30.0
    assert yaw_rate_setpoint(huge, end + 1e-4, 100.0, POLICY) == 0.0
    assert turn_ends_at(Decision(0.0, TurnCommand("forward", 0.0, 0.0)), POLICY) is None
    assert turn_ends_at(None, POLICY) is None


# ------------------------------------------------------------------ forward flight

FLY = OffboardConfig(enabled=True, stale_after_s=0.5, hold_after_s=3.0, confirm_timeout_s=3.0,
                     retry_after_s=5.0, forward_speed_m_s=1.0, forward_accel_m_s2=0.5)
FORWARD = TurnCommand("forward", 0.0, 0.0)
HOLD_CMD = TurnCommand("hold", 0.0, 0.0)


def fly(state, decision, now, yaw_deg=0.0, config=FLY, policy=POLICY):
    vehicle = VehicleStatus(True, armed=True, in_air=True, offboard=True, yaw_deg=yaw_deg)
    return supervise(state, vehicle, decision, now, config, policy)


def engaged(now=0.0, yaw_deg=0.0, config=FLY):
    """The first active tick (from engaging), at ``now``."""
    engaging = SupervisorState("engaging", True, vision_fresh=True, start_t_s=now,
                               tick_t_s=now)
    return fly(engaging, Decision(now, FORWARD), now, yaw_deg, config)


def test_forward_speed_ramps_up_from_zero_at_the_configured_acceleration():
    step = engaged()
    assert step.forward_m_s == 0.0  # no jump on engaging
    speeds = []
    for k in range(1, 41):  # 20 Hz for 2 s
        t = k * 0.05
        step = fly(step.state, Decision(t, FORWARD), t)
        speeds.append(step.forward_m_s)
    assert speeds[19] == pytest.approx(0.5)  # 1 s at 0.5 m/s²
    assert speeds[-1] == pytest.approx(1.0) and max(speeds) == 1.0
    assert all(b >= a for a, b in zip(speeds, speeds[1:], strict=False))


def test_forward_flight_goes_on_while_turning():
    step = engaged()
    for k in range(1, 60):
        step = fly(step.state, Decision(k * 0.05, FORWARD), k * 0.05)
    # η 20° seen from heading 0: Table II's heading 20°, lifted to min_avoid_deg.
    turning = fly(step.state, Decision(3.0, RIGHT, eta_deg=20.0, heading_deg=0.0), 3.0)
    assert POLICY.min_avoid_deg > 20.0
    assert turning.yaw_rate_deg_s == pytest.approx(POLICY.min_avoid_deg / POLICY.turn_time_s)
    assert turning.forward_m_s == 1.0


@pytest.mark.parametrize("why", ["hold", "stale"])
def test_forward_speed_drops_to_zero_at_once_on_hold_or_stalled_vision(why):
    step = engaged()
    for k in range(1, 60):
        step = fly(step.state, Decision(k * 0.05, FORWARD), k * 0.05)
    assert step.forward_m_s == 1.0
    if why == "hold":
        stopped = fly(step.state, Decision(3.0, HOLD_CMD), 3.0)
    else:
        stopped = fly(step.state, Decision(2.9, FORWARD), 2.9 + 0.51)
    assert stopped.stream and stopped.forward_m_s == 0.0 and stopped.yaw_rate_deg_s == 0.0
    # and the way back up is a ramp again, not a jump
    t = 3.0 if why == "hold" else 2.9 + 0.51
    again = fly(stopped.state, Decision(t + 0.2, FORWARD), t + 0.2)
    assert again.forward_m_s == pytest.approx(0.5 * 0.2)


def test_speed_zero_config_is_turn_in_place_as_before():
    hover = OffboardConfig(enabled=True, forward_speed_m_s=0.0)
    step = engaged(yaw_deg=40.0, config=hover)
    for k in range(1, 100):  # 5 s of no obstacle, 40° off the course it engaged at ... 0
        step = fly(step.state, Decision(k * 0.05, FORWARD), k * 0.05, yaw_deg=10.0,
                   config=hover)
        assert step.forward_m_s == 0.0 and step.yaw_rate_deg_s == 0.0


def see(state, t, eta, action, heading, target_heading=None):
    """A tick at ``t`` with a decision that saw η from ``heading``; the vehicle now at
    ``target_heading`` (default: ``heading``)."""
    command = TurnCommand(action, 0.0, 0.0) if action in ("forward", "hold") else (
        TurnCommand(action, eta, eta))
    now_heading = heading if target_heading is None else target_heading
    return fly(state, Decision(t, command, eta_deg=eta, heading_deg=heading), t, now_heading)


def test_the_heading_is_held_in_closed_loop_and_the_course_resumed_after_the_obstacle():
    step = engaged(yaw_deg=0.0)  # the course is 0°
    assert step.state.course_deg == 0.0
    # A face 40° right: Table II's target is 30° (max_turn_deg), flown as a heading.
    step = see(step.state, 0.1, 40.0, "right", 0.0)
    assert step.state.target_deg == 30.0 and step.yaw_rate_deg_s == 30.0
    # Between frames the rate follows the reported heading, not the frame's η.
    step = fly(step.state, Decision(0.1, RIGHT, 40.0, 0.0), 0.3, yaw_deg=20.0)
    assert step.yaw_rate_deg_s == pytest.approx(10.0 / POLICY.turn_time_s)
    # Aligned with the face (η in the deadband): hold that heading.
    step = see(step.state, 1.0, 1.0, "forward", 40.0)
    assert step.state.target_deg == pytest.approx(41.0) and step.yaw_rate_deg_s == 0.0
    # Out of view: not at once ...
    step = fly(step.state, Decision(1.5, FORWARD, None, 41.0), 1.5, yaw_deg=41.0)
    assert step.yaw_rate_deg_s == 0.0
    # ... nor resume_after_s later while the vehicle, still speeding up, has flown less
    # than full speed covers in that time (1 m) ...
    step = fly(step.state, Decision(2.1, FORWARD, None, 41.0), 2.1, yaw_deg=41.0)
    assert step.yaw_rate_deg_s == 0.0 and step.state.flown_since_seen_m < 1.0
    # ... but once it has: back left toward 0°, at most resume_max_rate_deg_s.
    step = fly(step.state, Decision(2.4, FORWARD, None, 41.0), 2.4, yaw_deg=41.0)
    assert step.state.flown_since_seen_m == pytest.approx(1.0)
    assert step.yaw_rate_deg_s == -POLICY.resume_max_rate_deg_s
    step = fly(step.state, Decision(3.0, FORWARD, None, 5.0), 3.0, yaw_deg=5.0)
    assert step.yaw_rate_deg_s == pytest.approx(-5.0 / POLICY.turn_time_s)
    step = fly(step.state, Decision(3.5, FORWARD, None, 2.0), 3.5, yaw_deg=2.0)
    assert step.yaw_rate_deg_s == 0.0  # in the deadband


def test_a_face_close_to_the_course_is_passed_at_least_min_avoid_deg_off_it():
    step = engaged(yaw_deg=10.0)  # course 10°
    step = see(step.state, 0.1, -12.0, "left", 10.0)  # face at -2°: 12° left of the course
    there = 10.0 - POLICY.min_avoid_deg
    assert step.state.target_deg == pytest.approx(there)
    # Once there, η reads the face right of the heading but there is no turn back:
    step = see(step.state, 1.5, -2.0 - there, "right", there)
    assert step.state.target_deg == pytest.approx(there) and step.yaw_rate_deg_s == 0.0


def test_a_turn_held_back_by_the_reversal_rule_keeps_the_target_and_hold_only_stops():
    step = engaged(yaw_deg=0.0)
    step = see(step.state, 0.1, 30.0, "right", 0.0)
    target = step.state.target_deg
    step = see(step.state, 0.3, -40.0, "forward", 10.0)  # a one-frame flip, held back
    assert step.state.target_deg == target and step.yaw_rate_deg_s > 0.0
    # Scene not understood: the vehicle stops, and keeps turning to the heading it has
    # (from earlier frames and telemetry), so that its view can change.
    step = fly(step.state, Decision(0.5, HOLD_CMD, None, 15.0), 0.5, yaw_deg=15.0)
    assert step.forward_m_s == 0.0 and step.yaw_rate_deg_s == pytest.approx(15.0)
    # and stale vision stops both
    step = fly(step.state, Decision(0.5, FORWARD, None, 15.0), 1.2, yaw_deg=15.0)
    assert step.forward_m_s == 0.0 and step.yaw_rate_deg_s == 0.0


def test_turn_slowdown_takes_the_share_of_the_turn_still_to_make():
    from dataclasses import replace as dc_replace

    slow = dc_replace(FLY, turn_slowdown=1.0)
    step = engaged(config=slow)
    for k in range(1, 60):
        step = fly(step.state, Decision(k * 0.05, FORWARD), k * 0.05, config=slow)
    assert step.forward_m_s == 1.0
    # A 30° target (max_turn_deg) from heading 0: the whole turn to make, so stopped ...
    step = fly(step.state, Decision(3.0, RIGHT, eta_deg=40.0, heading_deg=0.0), 3.0,
               config=slow)
    assert step.forward_m_s == 0.0 and step.yaw_rate_deg_s == 30.0
    # ... and with 15° still to go, at most half the speed: ramped up from 0 at
    # 0.5 m/s² for 0.5 s, 0.25 m/s, then up to the half and held there, however often
    # the supervisor ticks (a factor applied every tick would shrink it to a crawl).
    step = fly(step.state, Decision(3.0, RIGHT, 40.0, 0.0), 3.5, yaw_deg=15.0, config=slow)
    assert step.forward_m_s == pytest.approx(0.5 * 0.5)
    for k in range(1, 41):
        step = fly(step.state, Decision(3.0 + k * 0.05, RIGHT, 40.0, 0.0),
                   3.5 + k * 0.05, yaw_deg=15.0, config=slow)
    assert step.forward_m_s == pytest.approx(0.5)


# ------------------------------------------------------------------ range


def cruising(t_end=3.0):
    """Engaged at 0 and flown at full speed (1 m/s) until ``t_end``, no obstacle."""
    step = engaged()
    for k in range(1, int(round(t_end / 0.05)) + 1):
        step = fly(step.state, Decision(k * 0.05, FORWARD), k * 0.05)
    assert step.forward_m_s == 1.0
    return step


def test_an_obstacle_close_in_the_path_slows_the_vehicle_and_a_closer_one_stops_it():
    assert (POLICY.stop_within_m, POLICY.slow_within_m) == (0.8, 2.0)
    step = cruising()
    # 1.4 m ahead in the path: half-way between stop and slow, half the speed, at once.
    step = fly(step.state, Decision(3.0, RIGHT, 40.0, 0.0, range_m=1.4, path_m=1.4), 3.0)
    assert step.forward_m_s == pytest.approx(0.5) and step.yaw_rate_deg_s == 30.0
    # 0.7 m: stopped, still turning away.
    step = fly(step.state, Decision(3.2, RIGHT, 40.0, 0.0, range_m=0.7, path_m=0.7), 3.2)
    assert step.forward_m_s == 0.0 and step.yaw_rate_deg_s == 30.0
    # The obstacle measured beside the path (inf): full speed is ramped back to.
    step = fly(step.state, Decision(3.4, FORWARD, 1.0, 30.0, range_m=0.9,
                                    path_m=float("inf")), 3.4, yaw_deg=30.0)
    assert step.forward_m_s == pytest.approx(0.5 * 0.2)


def test_a_path_distance_is_dead_reckoned_while_the_foot_is_out_of_view_then_dropped():
    step = cruising()
    step = fly(step.state, Decision(3.0, FORWARD, 2.0, 0.0, range_m=1.9, path_m=1.9), 3.0)
    assert step.forward_m_s == pytest.approx((1.9 - 0.8) / 1.2)
    # Frames still see the obstacle, its foot below the view: the distance shrinks with
    # what was flown, and the vehicle slows on toward a stop short of stop_within_m
    # (speed in proportion to the distance left: it decays, time constant 1.2 s here).
    speeds = []
    for k in range(1, 40):
        t = 3.0 + k * 0.05
        frame_t = 3.0 + 0.2 * (k // 4)  # a 5 Hz camera
        step = fly(step.state, Decision(frame_t, FORWARD, 2.0, 0.0), t)
        speeds.append(step.forward_m_s)
    assert 0.8 < step.state.path_m < 1.05 and speeds[-1] < 0.2
    assert all(b <= a for a, b in zip(speeds, speeds[1:], strict=False))
    # A frame without any obstacle forgets it: the ramp starts again.
    step = fly(step.state, Decision(5.0, FORWARD), 5.0)
    assert step.state.path_m is None and step.forward_m_s > 0.0
    # Nor is a distance kept for longer than PATH_MEMORY_S without a measurement.
    from companion.control.supervisor import PATH_MEMORY_S
    step = fly(step.state, Decision(6.0, FORWARD, 2.0, 0.0, range_m=5.0, path_m=5.0), 6.0)
    t = 6.0 + PATH_MEMORY_S + 0.05
    step = fly(step.state, Decision(t, FORWARD, 2.0, 0.0), t)
    assert step.state.path_m is None


def test_an_obstacle_beyond_act_within_sets_no_target_and_the_course_resumes():
    assert POLICY.act_within_m == 6.0
    step = engaged(yaw_deg=0.0)
    step = fly(step.state, Decision(0.1, FORWARD, 40.0, 0.0, range_m=9.0, path_m=9.0), 0.1)
    assert step.state.target_deg is None and step.state.obstacle_t_s is None
    step = fly(step.state, Decision(0.3, RIGHT, 40.0, 0.0, range_m=5.0, path_m=5.0), 0.3)
    assert step.state.target_deg == 30.0


def test_an_unconfirmed_detection_sets_no_target_until_its_foot_is_measured():
    ranged = replace(POLICY, unconfirmed="ranged")
    step = engaged(yaw_deg=0.0)
    # One frame, not confirmed by the tracker, no foot measured: no turn ...
    lone = Decision(0.1, RIGHT, 40.0, 0.0, confirmed=False)
    step = fly(step.state, lone, 0.1, policy=ranged)
    assert step.state.target_deg is None and step.yaw_rate_deg_s == 0.0
    assert step.state.obstacle_t_s == 0.1  # ... but seen: the course waits for it to pass
    # The next frame confirms it: the target is set from that frame's η.
    step = fly(step.state, Decision(0.3, RIGHT, 40.0, 0.0), 0.3, policy=ranged)
    assert step.state.target_deg == 30.0
    # Not confirmed, but its foot measured within act_within_m: flown at once.
    step = engaged(yaw_deg=0.0)
    step = fly(step.state, Decision(0.1, RIGHT, 40.0, 0.0, range_m=4.0, confirmed=False), 0.1,
               policy=ranged)
    assert step.state.target_deg == 30.0
    # The default, as the paper (unconfirmed: fly): every frame's η is flown.
    assert POLICY.unconfirmed == "fly"
    step = engaged(yaw_deg=0.0)
    step = fly(step.state, lone, 0.1)
    assert step.state.target_deg == 30.0


def test_range_never_speeds_up_hovering_or_stale_vision():
    hover = OffboardConfig(enabled=True, forward_speed_m_s=0.0)
    step = engaged(config=hover)
    step = fly(step.state, Decision(0.1, RIGHT, 20.0, 0.0, range_m=3.0, path_m=3.0), 0.1,
               config=hover)
    assert step.forward_m_s == 0.0 and step.yaw_rate_deg_s == 20.0
    step = cruising()
    stale = fly(step.state, Decision(3.0, FORWARD, 2.0, 0.0, range_m=9.0, path_m=9.0), 3.6)
    assert stale.forward_m_s == 0.0


def test_a_vehicle_slowed_by_range_resumes_the_course_only_once_it_has_flown_past():
    step = cruising()  # course 0°, 1 m/s
    # An obstacle 1.1 m ahead in the path: a quarter of the speed (slow 2 m, stop 0.8 m).
    step = fly(step.state, Decision(3.0, RIGHT, 40.0, 0.0, range_m=1.1, path_m=1.1), 3.0)
    assert step.forward_m_s == pytest.approx(0.25)
    t, flown_at_resume = 3.0, None
    while t < 12.0 and flown_at_resume is None:  # out of view from the next frame on
        t = round(t + 0.05, 2)
        step = fly(step.state, Decision(t, FORWARD), t, yaw_deg=30.0)
        if step.yaw_rate_deg_s < 0.0:  # turning back to the course
            flown_at_resume = step.state.flown_since_seen_m
    # Not after resume_after_s (1 s at a quarter speed and ramping is well short of 1 m) ...
    assert t > 3.0 + POLICY.resume_after_s + 0.2
    # ... but once 1 m (what full speed covers in resume_after_s) had been flown.
    assert flown_at_resume == pytest.approx(1.0, abs=0.06)


def test_the_pass_off_stays_on_the_side_taken_until_the_vehicle_is_back_on_the_course():
    step = engaged(yaw_deg=0.0)  # course 0°
    step = see(step.state, 0.1, 40.0, "right", 0.0, 29.0)  # the face 40° right: pass right
    assert step.state.target_deg == 30.0 and step.state.pass_side == 1
    # Beside the box, a frame reads a face 12° left of the course (a rug's corner read as
    # the box's foot): with the side kept, the heading stays right of the course.
    step = see(step.state, 0.5, -41.0, "left", 29.0)
    assert step.state.target_deg == 30.0 and step.yaw_rate_deg_s >= 0.0
    assert step.state.obstacle_t_s == 0.5  # still an obstacle in view: no resume yet
    # Something measured in the path changes that: the frame is acted on.
    blocked = fly(step.state, Decision(0.7, TurnCommand("left", -41.0, -30.0), eta_deg=-41.0,
                                       heading_deg=29.0, path_m=1.0), 0.7, 29.0)
    assert blocked.state.target_deg == pytest.approx(-1.0) and blocked.state.pass_side == -1
    # Without keep_pass_side, the lone frame turns the vehicle back across the course.
    from dataclasses import replace as dc_replace
    free = supervise(step.state, VehicleStatus(True, True, True, True, yaw_deg=29.0),
                     Decision(0.7, TurnCommand("left", -41.0, -30.0), eta_deg=-41.0,
                              heading_deg=29.0), 0.7, FLY,
                     dc_replace(POLICY, keep_pass_side=False))
    assert free.state.target_deg == pytest.approx(-1.0) and free.yaw_rate_deg_s < 0.0
    # Kept: out of view, the course resumes; back on it, the next obstacle picks anew.
    t = 0.5
    while t < 10.0 and step.state.pass_side != 0:
        t = round(t + 0.05, 2)
        step = fly(step.state, Decision(t, FORWARD), t, yaw_deg=max(0.0, 30.0 - 10.0 * (t - 2.5)))
    assert step.state.pass_side == 0 and abs(step.state.course_deg) < 1e-9
    step = see(step.state, t + 0.05, -20.0, "left", 0.0)
    assert step.state.target_deg == -30.0 and step.state.pass_side == -1


def test_without_resume_course_the_side_is_released_once_the_obstacle_is_passed():
    from dataclasses import replace as dc_replace

    policy = dc_replace(POLICY, resume_course=False)
    vehicle = VehicleStatus(True, armed=True, in_air=True, offboard=True, yaw_deg=30.0)
    step = engaged(yaw_deg=0.0)
    step = supervise(step.state, vehicle, Decision(0.1, RIGHT, 40.0, 0.0), 0.1, FLY, policy)
    assert step.state.pass_side == 1
    t = 0.1
    while t < 10.0 and step.state.pass_side != 0:  # out of view, still 30° off the course
        t = round(t + 0.05, 2)
        step = supervise(step.state, vehicle, Decision(t, FORWARD), t, FLY, policy)
        assert step.yaw_rate_deg_s == 0.0  # no course to resume: the heading is held
    assert step.state.pass_side == 0 and t >= 0.1 + policy.resume_after_s


def test_a_new_engagement_flies_nothing_an_earlier_one_saw():
    step = engaged(yaw_deg=0.0)
    step = see(step.state, 0.1, 40.0, "right", 0.0)  # pass right, toward 30°
    assert step.state.target_deg == 30.0 and step.state.pass_side == 1
    # The pilot takes over, flies elsewhere, and offboard is enabled again at heading 90°.
    pilot = VehicleStatus(True, armed=True, in_air=True, offboard=False, yaw_deg=90.0)
    step = supervise(step.state, pilot, Decision(0.2, FORWARD), 0.2, FLY, POLICY)
    assert step.state.name == "disabled"
    step = supervise(enable(step.state), pilot, Decision(20.0, FORWARD), 20.0, FLY, POLICY)
    assert step.state.name == "engaging"
    for k in range(1, 30):  # 1.5 s with nothing in view: no turn, on the new course
        t = 20.0 + 0.05 * k
        step = fly(step.state, Decision(t, FORWARD), t, yaw_deg=90.0)
        assert step.state.name == "active" and step.yaw_rate_deg_s == 0.0
    assert step.state.course_deg == 90.0 and step.state.target_deg is None
    assert step.state.pass_side == 0 and step.state.obstacle_t_s is None


def test_the_side_is_kept_back_on_the_course_until_the_foot_measured_is_abeam():
    step = cruising()  # course 0°, ramped up to 1 m/s over 3 s: about 2 m along it
    # A face 20° left, its foot measured 5 m ahead: pass left, at min_avoid_deg.
    step = fly(step.state, Decision(3.0, TurnCommand("left", -20.0, -20.0), -20.0, 0.0,
                                    range_m=5.0, path_m=float("inf")), 3.0)
    assert step.state.pass_side == -1 and step.state.target_deg == -POLICY.min_avoid_deg
    foot_m = step.state.course_progress_m + 5.0
    assert step.state.foot_abeam_m == pytest.approx(foot_m)
    # Out of view for 2 s, then 2 s back toward the course: about 3.6 m more along it.
    t = 3.0
    while t < 7.0:
        t = round(t + 0.05, 2)
        yaw = -POLICY.min_avoid_deg if t < 5.0 else min(0.0, -30.0 + 15.0 * (t - 5.0))
        step = fly(step.state, Decision(t, FORWARD), t, yaw_deg=yaw)
    assert step.state.course_progress_m < foot_m and step.state.pass_side == -1
    # Back on the course short of the foot, a frame reads the obstacle's other face (a
    # right turn toward it): held back; the pass-off heading is flown again.
    step = fly(step.state, Decision(7.05, TurnCommand("right", 26.0, 26.0), 26.0, 0.0,
                                    range_m=4.0, path_m=float("inf")), 7.05)
    assert step.state.pass_side == -1 and step.yaw_rate_deg_s < 0.0
    # Back on the course, the side is released once that foot (4 m ahead) is abeam.
    abeam_m, t = step.state.course_progress_m + 4.0, 7.05
    while step.state.pass_side != 0 and t < 30.0:
        t = round(t + 0.05, 2)
        step = fly(step.state, Decision(t, FORWARD), t)
    assert abeam_m <= step.state.course_progress_m <= abeam_m + 0.05


def test_floor_contacts_are_remembered_in_the_course_frame_and_forgotten_once_behind():
    from companion.control.supervisor import remembered_contacts

    state = SupervisorState("active", True, contacts_m=((0.5, 0.0), (3.0, 1.0)))
    # A frame taken facing 90° right of the course (0°), the vehicle 1 m along it and 2 m
    # right: a foot 2 m ahead and 1 m right of the camera is 1 m back along the course and
    # 4 m right of it; one 7 m away is beyond act_within_m (6 m): not remembered.
    decision = Decision(1.0, FORWARD, heading_deg=90.0, contacts_m=((2.0, 1.0), (7.0, 0.0)))
    contacts, since = remembered_contacts(state, decision, True, 0.0, 1.0, 2.0, POLICY)
    assert since == 1.0 and contacts[:2] == ((0.5, 0.0), (3.0, 1.0))  # 0.5 m behind: kept
    assert len(contacts) == 3 and contacts[2] == pytest.approx((0.0, 4.0))
    # The same decision at the next tick adds nothing; 1.6 m on, the one 0.5 m along the
    # course is more than resume_clearance_m behind: forgotten.
    moved = replace(state, contacts_m=contacts, contacts_t_s=since)
    later, _ = remembered_contacts(moved, decision, True, 0.0, 1.6, 2.0, POLICY)
    assert later == ((3.0, 1.0),)
    # Stale vision, or no heading for the frame: nothing is added.
    assert remembered_contacts(state, decision, False, 0.0, 1.0, 2.0, POLICY)[1] is None
    assert remembered_contacts(state, replace(decision, heading_deg=None), True, 0.0, 1.0,
                               2.0, POLICY)[0] == ((0.5, 0.0), (3.0, 1.0))


def test_a_foot_measured_again_replaces_its_earlier_measurement():
    from companion.control.supervisor import CONTACT_MERGE_M, remembered_contacts

    # A foot seen 3 m ahead, then from 0.5 m nearer as 2.45 m ahead (5 cm off): one point,
    # the newer; a point of the floor behind it, 0.25 m on, stays a point of its own.
    first = Decision(1.0, FORWARD, heading_deg=0.0, contacts_m=((3.0, 0.0), (3.25, 0.0)))
    contacts, since = remembered_contacts(SupervisorState("active", True), first, True, 0.0,
                                          0.0, 0.0, POLICY)
    assert contacts == ((3.0, 0.0), (3.25, 0.0))
    again = Decision(1.2, FORWARD, heading_deg=0.0, contacts_m=((2.45, 0.0),))
    state = SupervisorState("active", True, contacts_m=contacts, contacts_t_s=since)
    contacts, _ = remembered_contacts(state, again, True, 0.0, 0.5, 0.0, POLICY)
    assert contacts == ((3.25, 0.0), (2.95, 0.0))
    assert 0.05 < CONTACT_MERGE_M < 0.25


def test_a_contact_the_vehicle_flies_over_is_forgotten():
    from companion.control.supervisor import remembered_contacts

    # The vehicle 2 m along the course and 1 m right of it: a contact 0.2 m from it is
    # where it flies (within half resume_clearance_m, 0.25 m); one 0.3 m away is kept.
    state = SupervisorState("active", True, contacts_m=((2.2, 1.0), (2.0, 1.3), (4.0, 1.0)))
    contacts, _ = remembered_contacts(state, None, False, 0.0, 2.0, 1.0, POLICY)
    assert 0.2 < 0.5 * POLICY.resume_clearance_m < 0.3
    assert contacts == ((2.0, 1.3), (4.0, 1.0))


HELD = replace(POLICY, least_turn=False)  # the pass-off heading held as Table II sets it


def resume_past(contacts, policy=HELD):
    """Cruise along 0°, see a face 40° right with ``contacts`` (ahead, right of the camera,
    m) at 3 s, fly the pass-off heading (30°) with nothing more in view, and return the
    time the vehicle starts back toward the course and the state then."""
    step = cruising()
    step = fly(step.state, Decision(3.0, RIGHT, 40.0, 0.0, contacts_m=contacts), 3.0,
               policy=policy)
    assert step.state.target_deg == 30.0
    t = 3.0
    while t < 20.0:
        t = round(t + 0.05, 2)
        step = fly(step.state, Decision(t, FORWARD), t, yaw_deg=30.0, policy=policy)
        if step.yaw_rate_deg_s < 0.0:
            return t, step.state
        assert step.yaw_rate_deg_s == 0.0  # the pass-off heading is held
    raise AssertionError("never resumed")


def test_the_course_resumes_only_on_a_path_clear_of_the_feet_measured_earlier():
    from companion.control.policy import resume_path_clearance_m

    clear_t, _ = resume_past(())
    assert clear_t == pytest.approx(3.0 + POLICY.resume_after_s, abs=0.06)
    # Feet beside the course the vehicle is leaving: the resume's path stays clear of them.
    assert resume_past(((3.0, -1.0), (4.0, -0.5)))[0] == clear_t
    # A box rotated away from the course: its near foot 2.5 m ahead, its far one 4.5 m
    # ahead and 1.3 m right, where the path back from the pass-off heading would cross.
    far = (4.5, 1.3)
    t, state = resume_past(((2.5, 0.2), far))
    assert t > clear_t + 0.5
    # It resumed once the predicted path kept resume_clearance_m from the far foot ...
    along, across = state.course_progress_m, state.course_offset_m
    foot = (2.0 + far[0], far[1])  # the vehicle was 2 m along the course when it saw it
    assert state.contacts_m[-1] == pytest.approx(foot, abs=0.05)
    assert resume_path_clearance_m((foot,), along, across, 30.0, FLY.forward_speed_m_s,
                                   POLICY) >= POLICY.resume_clearance_m
    # ... and held the pass-off heading one tick before, when it did not.
    back = 1.0 * 0.05  # one tick at 1 m/s, on the pass-off heading
    assert resume_path_clearance_m(
        (foot,), along - back * math.cos(math.radians(30.0)),
        across - back * math.sin(math.radians(30.0)), 30.0, FLY.forward_speed_m_s,
        POLICY) < POLICY.resume_clearance_m
    # With the rule off, the course resumes at the usual time.
    assert resume_past(((2.5, 0.2), far), replace(HELD, resume_clearance_m=0.0))[0] == clear_t


def test_contacts_along_the_path_flown_hold_off_the_course_only_until_flown_over():
    # A frame that misread the box put its "feet" on the very line the pass-off heading
    # (30°) flies, 1 to 3 m on from where the vehicle saw it (2 m along the course).
    ray = tuple((d * math.cos(math.radians(30.0)), d * math.sin(math.radians(30.0)))
                for d in (1.0, 1.5, 2.0, 2.5, 3.0))
    clear_t, _ = resume_past(())
    t, state = resume_past(ray)
    assert t > clear_t + 0.5  # the path back met those still ahead
    # It resumed as soon as it had flown over the last: all are forgotten, and it is
    # still beside where that one was (remembered, the path back from here meets it).
    last = (2.0 + ray[-1][0], ray[-1][1])
    assert state.contacts_m == ()
    assert math.hypot(state.course_progress_m - last[0],
                      state.course_offset_m - last[1]) < POLICY.resume_clearance_m


def resume_in_view(policy=HELD, range_m=3.0, until=12.0):
    """Cruise along 0°, see a face across the course at 3 s (feet 2.5 m ahead, 0.6 m either
    side of it), fly the pass-off heading (30°) with the face still in view on every
    frame, its foot measured (``range_m``) or not (None), and return the time the vehicle
    starts back toward the course (None: not before ``until``) and the state then."""
    step = cruising()
    step = fly(step.state, Decision(3.0, RIGHT, 40.0, 0.0, range_m=2.5,
                                    contacts_m=((2.5, 0.6), (2.5, -0.6))), 3.0, policy=policy)
    assert step.state.target_deg == 30.0
    t = 3.0
    while t < until:
        t = round(t + 0.05, 2)
        seen = Decision(t, FORWARD, 5.0, 30.0, range_m=range_m)  # aligned enough: no new turn
        step = fly(step.state, seen, t, yaw_deg=30.0, policy=policy)
        if step.yaw_rate_deg_s < 0.0:
            return t, step.state
        assert step.yaw_rate_deg_s == 0.0
    return None, step.state


def test_in_view_the_course_resumes_once_the_path_back_clears_the_feet_measured():
    from companion.control.policy import resume_path_clearance_m

    t, state = resume_in_view()
    assert t is not None and state.obstacle_t_s == t  # resumed with the face in view
    feet = state.contacts_m
    assert len(feet) == 2
    args = (FLY.forward_speed_m_s, POLICY)
    assert resume_path_clearance_m(feet, state.course_progress_m, state.course_offset_m, 30.0,
                                   *args) >= POLICY.resume_clearance_m
    back = 1.0 * 0.05  # one tick earlier on the pass-off heading: the path back met a foot
    assert resume_path_clearance_m(
        feet, state.course_progress_m - back * math.cos(math.radians(30.0)),
        state.course_offset_m - back * math.sin(math.radians(30.0)), 30.0,
        *args) < POLICY.resume_clearance_m
    # Not while the frames see it without measuring its foot, nor with the rule off: the
    # pass-off heading is held as long as the face is in view.
    assert resume_in_view(range_m=None)[0] is None
    assert resume_in_view(replace(HELD, resume_in_view=False))[0] is None


def test_a_piece_whose_feet_are_measured_clear_of_the_course_is_not_turned_for():
    beside = Decision(3.0, RIGHT, 40.0, 0.0, range_m=3.0,
                      contacts_m=((3.0, -2.0), (3.5, -1.5)))  # 1.5 m left of the course
    assert fly(cruising().state, beside, 3.0, policy=HELD).yaw_rate_deg_s == 0.0
    off = replace(HELD, resume_in_view=False)
    assert fly(cruising().state, beside, 3.0, policy=off).yaw_rate_deg_s == 30.0
    # The least turn alone keeps the pass-off angle: it is turned for.
    least = replace(POLICY, resume_in_view=False)
    assert fly(cruising().state, beside, 3.0, policy=least).yaw_rate_deg_s == 30.0
    # In the path, it is turned for.
    ahead = replace(beside, contacts_m=((3.0, -0.3), (3.5, 0.2)))
    assert fly(cruising().state, ahead, 3.0, policy=HELD).yaw_rate_deg_s == 30.0


def test_back_on_the_course_a_foot_measured_in_its_path_turns_it_to_the_pass_off_again():
    step = cruising()  # course 0°, about 2 m along it
    step = fly(step.state, Decision(3.0, RIGHT, 40.0, 0.0, contacts_m=((5.0, 0.0),)), 3.0,
               policy=HELD)
    assert step.state.target_deg == 30.0
    t = 3.0
    while t < 6.0:  # on the course, nothing in view, the foot 5 m ahead on it
        t = round(t + 0.05, 2)
        step = fly(step.state, Decision(t, FORWARD), t, yaw_deg=0.0, policy=HELD)
    assert step.state.course_progress_m < step.state.contacts_m[0][0]
    assert step.yaw_rate_deg_s == POLICY.max_yaw_rate_deg_s  # toward 30°, not held at 0°
    off = fly(step.state, Decision(6.05, FORWARD), 6.05, yaw_deg=0.0,
              policy=replace(HELD, resume_clearance_m=0.0))
    assert off.yaw_rate_deg_s == 0.0


def test_past_measured_feet_the_least_turn_that_clears_them_is_flown():
    from companion.control.policy import clearing_heading

    wide = replace(POLICY, max_turn_deg=45.0, resume_in_view=False)

    def settle(policy):
        """Cruise along 0°, see a face 42° right, its foot from 4.0 m ahead and 0.4 m left
        to 4.8 m ahead and 2.0 m right, then fly on with it in view (each frame sees it
        42° right of the course), the heading following the yaw rate streamed; the
        heading after 3 s."""
        step = cruising()
        feet = tuple((4.0 + 0.8 * k / 10, -0.4 + 2.4 * k / 10) for k in range(11))
        step = fly(step.state, Decision(3.0, RIGHT, 42.0, 0.0, range_m=4.0, contacts_m=feet),
                   3.0, policy=policy)
        yaw, t = 0.0, 3.0
        while t < 6.0:
            yaw += step.yaw_rate_deg_s * 0.05
            t = round(t + 0.05, 2)
            eta = 42.0 - yaw
            seen = Decision(t, RIGHT if eta > POLICY.deadband_deg else FORWARD, eta, yaw)
            step = fly(step.state, seen, t, yaw_deg=yaw, policy=policy)
        return yaw, step.state

    # Table II's heading, approached until within the deadband.
    held, _ = settle(replace(wide, least_turn=False))
    assert held == pytest.approx(42.0, abs=POLICY.deadband_deg + 0.1)
    # The least turn: short of the face's, and not short of the pass-off angle ...
    least, state = settle(wide)
    assert POLICY.min_avoid_deg - POLICY.deadband_deg <= least < held - POLICY.deadband_deg
    # ... within the deadband of the least heading whose path clears the feet from where
    # the vehicle now is.
    assert least == pytest.approx(clearing_heading(
        state.contacts_m, state.course_progress_m, state.course_offset_m, 0.0,
        state.target_deg, wide), abs=POLICY.deadband_deg + 1.0)
