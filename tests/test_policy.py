"""Table II: η → left / right / forward, the cap, the deadband, the yaw rate."""

import math

import pytest

from companion.config import PolicyConfig
from companion.control.policy import decide_turn, obstacle_matters, path_speed_scale

P = PolicyConfig(max_turn_deg=30.0, deadband_deg=3.0, turn_time_s=1.0, max_yaw_rate_deg_s=25.0)


def test_positive_eta_turns_right_with_positive_yaw_rate():
    cmd = decide_turn(12.0, P)
    assert (cmd.action, cmd.turn_deg, cmd.yaw_rate_deg_s) == ("right", 12.0, 12.0)


def test_negative_eta_turns_left():
    cmd = decide_turn(-10.0, P)
    assert (cmd.action, cmd.turn_deg, cmd.yaw_rate_deg_s) == ("left", -10.0, -10.0)


def test_turn_capped_at_max_turn_angle_and_rate_capped():
    cmd = decide_turn(76.43, P)
    assert cmd.turn_deg == 30.0
    assert cmd.yaw_rate_deg_s == 25.0
    assert decide_turn(-80.0, P).turn_deg == -30.0


@pytest.mark.parametrize("eta", [0.0, 2.9, -3.0, None])
def test_deadband_and_no_obstacle_go_forward(eta):
    cmd = decide_turn(eta, P)
    assert (cmd.action, cmd.yaw_rate_deg_s) == ("forward", 0.0)


def test_no_scene_understanding_or_nan_holds():
    assert decide_turn(20.0, P, scene_understood=False).action == "hold"
    assert decide_turn(math.nan, P).action == "hold"
    assert decide_turn(math.nan, P).yaw_rate_deg_s == 0.0


def test_a_reversal_needs_two_frames_in_a_row():
    from companion.control.policy import TurnHistory, confirm_reversal

    history = TurnHistory()
    actions = []
    for eta in (-20.0, -8.0, 1.0, 25.0, 1.0, 15.0, 12.0, 9.0, -10.0):
        cmd, history = confirm_reversal(decide_turn(eta, P), history)
        actions.append(cmd.action)
    # left, left, forward; one stray right is not flown; two rights in a row are; then a
    # single left against them is not.
    assert actions == ["left", "left", "forward", "forward", "forward", "forward", "right",
                       "right", "forward"]
    assert cmd.yaw_rate_deg_s == 0.0


def test_avoidance_heading_is_table_ii_plus_a_pass_off_angle():
    from companion.control.policy import avoidance_heading

    p = PolicyConfig(max_turn_deg=30.0, min_avoid_deg=25.0)
    assert avoidance_heading(28.0, 0.0, 0.0, p) == pytest.approx(28.0)  # Table II: turn by η
    assert avoidance_heading(40.0, 0.0, 0.0, p) == pytest.approx(30.0)  # capped per decision
    assert avoidance_heading(12.0, 0.0, 0.0, p) == pytest.approx(25.0)  # lifted off the course
    assert avoidance_heading(-14.0, 5.0, 0.0, p) == pytest.approx(-25.0)  # face 9° left
    assert avoidance_heading(-30.0, 170.0, 170.0, p) == pytest.approx(140.0)
    assert avoidance_heading(20.0, 170.0, 170.0, p) == pytest.approx(-165.0)  # across ±180°
    paper = PolicyConfig(max_turn_deg=30.0, min_avoid_deg=0.0)
    assert avoidance_heading(12.0, 3.0, 0.0, paper) == pytest.approx(15.0)


def test_heading_rate_is_table_ii_rate_toward_the_target():
    from companion.control.policy import heading_rate

    p = PolicyConfig(deadband_deg=3.0, turn_time_s=1.0, max_yaw_rate_deg_s=30.0)
    assert heading_rate(20.0, 0.0, p) == 20.0
    assert heading_rate(-60.0, 0.0, p) == -30.0
    assert heading_rate(-175.0, 175.0, p) == 10.0  # the short way, across ±180°
    assert heading_rate(2.0, 0.0, p) == 0.0
    assert heading_rate(0.0, 20.0, p, max_rate_deg_s=10.0) == -10.0


def test_an_obstacle_measured_beyond_act_within_is_not_turned_for():
    p = PolicyConfig(act_within_m=6.0)
    assert decide_turn(20.0, p, range_m=5.9).action == "right"
    assert decide_turn(20.0, p, range_m=6.1).action == "forward"
    assert decide_turn(20.0, p, range_m=None).action == "right"  # not measured: it matters
    assert obstacle_matters(50.0, PolicyConfig(act_within_m=0.0))  # 0: rule off
    assert decide_turn(20.0, p, scene_understood=False, range_m=9.0).action == "hold"


def test_path_speed_scale_falls_from_slow_within_to_stop_within():
    p = PolicyConfig(slow_within_m=2.0, stop_within_m=1.0)
    assert [path_speed_scale(d, p) for d in (None, math.inf, 3.0, 2.0, 1.5, 1.0, 0.2)] == [
        1.0, 1.0, 1.0, 1.0, 0.5, 0.0, 0.0]
    assert path_speed_scale(0.5, PolicyConfig(slow_within_m=0.0)) == 1.0  # rule off


def test_steering_eta_is_the_frames_unless_a_confirmed_track_is_asked_for():
    from companion.control.policy import steering_eta

    per_frame = PolicyConfig()  # every frame's η, as the paper
    assert steering_eta(44.0, -46.0, per_frame) == 44.0
    assert steering_eta(12.0, None, per_frame) == 12.0
    assert steering_eta(None, 20.0, per_frame) is None  # no bridging without the track
    tracked = PolicyConfig(steer_by_track=True, unconfirmed="wait")
    assert steering_eta(44.0, -46.0, tracked) == -46.0  # the track's face, held
    assert steering_eta(12.0, None, tracked) is None  # one frame, not yet confirmed: no turn
    assert steering_eta(None, 20.0, tracked) == 20.0  # a dropout bridged by the track
    assert steering_eta(12.0, None, tracked, range_m=3.0) is None  # wait: even if ranged


def test_an_unconfirmed_detection_is_turned_for_once_its_foot_is_measured():
    from companion.control.policy import steering_eta, turns_for

    assert PolicyConfig().unconfirmed == "fly"  # the default: the paper, every frame's η
    ranged = PolicyConfig(unconfirmed="ranged")
    assert turns_for(True, None, ranged)  # confirmed by the tracker
    assert not turns_for(False, None, ranged)  # one frame, no foot measured
    assert turns_for(False, 3.0, ranged) and turns_for(False, 30.0, ranged)  # act_within_m
    assert turns_for(False, None, PolicyConfig(unconfirmed="fly"))  # the paper
    assert not turns_for(False, 3.0, PolicyConfig(unconfirmed="wait"))
    # The per-frame decision stays the paper's (the log's action follows its η); the
    # supervisor applies the rule in forward flight. Steered by the track, the decision:
    assert steering_eta(12.0, None, ranged) == 12.0
    tracked = PolicyConfig(steer_by_track=True, unconfirmed="ranged")
    assert steering_eta(12.0, None, tracked) is None
    assert steering_eta(12.0, None, tracked, range_m=3.0) == 12.0
    assert steering_eta(44.0, -46.0, tracked, range_m=3.0) == -46.0  # the track still wins
    assert steering_eta(12.0, None, PolicyConfig(steer_by_track=True)) == 12.0  # fly


def test_decide_frame_steers_by_the_track_only_when_asked_and_confirms_reversals():
    from companion.control.policy import TurnHistory, decide_frame

    per_frame = PolicyConfig()
    by_track = PolicyConfig(steer_by_track=True, unconfirmed="ranged")
    # The frame says left, the confirmed track says right.
    eta, cmd, _ = decide_frame(-20.0, 25.0, per_frame, TurnHistory())
    assert (eta, cmd.action) == (-20.0, "left")
    eta, cmd, _ = decide_frame(-20.0, 25.0, by_track, TurnHistory())
    assert (eta, cmd.action) == (25.0, "right")
    eta, cmd, _ = decide_frame(-20.0, None, by_track, TurnHistory())  # no track yet
    assert (eta, cmd.action) == (None, "forward")
    # No track yet, the foot measured: near, flown; beyond act_within_m, not yet.
    eta, cmd, _ = decide_frame(-20.0, None, by_track, TurnHistory(), range_m=3.0)
    assert (eta, cmd.action) == (-20.0, "left")
    assert decide_frame(-20.0, None, by_track, TurnHistory(), range_m=9.0)[1].action == "forward"
    # After a right turn, a left is flown only on the second frame asking for it.
    history = TurnHistory()
    actions = []
    for frame_eta in (20.0, -20.0, -20.0):
        _, cmd, history = decide_frame(frame_eta, None, per_frame, history)
        actions.append(cmd.action)
    assert actions == ["right", "forward", "left"]
    # Range and scene understanding reach Table II.
    far = PolicyConfig(act_within_m=6.0)
    assert decide_frame(-20.0, None, far, TurnHistory(), range_m=9.0)[1].action == "forward"
    assert decide_frame(-20.0, None, far, TurnHistory(), False)[1].action == "hold"


def test_the_pass_side_is_where_the_face_points_off_the_course():
    from companion.control.policy import pass_side

    assert pass_side(20.0, 0.0, 0.0) == 1 and pass_side(-20.0, 0.0, 0.0) == -1
    # From a heading 29° right, a face read 40° left points 11° left of the course.
    assert pass_side(-40.0, 29.0, 0.0) == -1 and pass_side(-20.0, 29.0, 0.0) == 1
    assert pass_side(10.0, 170.0, -175.0) == -1  # across ±180°: 5° left of the course


def test_a_frame_asking_for_the_other_side_is_held_back_unless_the_path_is_blocked():
    from companion.control.policy import keeps_side

    p = PolicyConfig(slow_within_m=3.5)
    assert not keeps_side(-1, 0, None, p)  # no side taken yet
    assert not keeps_side(1, 1, None, p)  # the same side
    assert keeps_side(-1, 1, None, p) and keeps_side(-1, 1, 5.0, p)
    assert keeps_side(-1, 1, math.inf, p)  # measured: the path is clear
    assert not keeps_side(-1, 1, 3.0, p)  # something in the path: the side may change
    assert not keeps_side(-1, 1, None, PolicyConfig(keep_pass_side=False))


def test_the_resume_is_predicted_as_flown_a_circle_at_the_capped_rate_then_straight():
    from companion.control.policy import resume_path_clearance_m

    p = PolicyConfig(turn_time_s=1.0, deadband_deg=3.0, resume_max_rate_deg_s=10.0)
    assert resume_path_clearance_m((), 0.0, 0.0, 30.0, 1.0, p) == math.inf
    # On the course already: a straight line along it, at least 8 m long (the horizon
    # at 1 m/s).
    assert resume_path_clearance_m(((3.0, 0.8),), 1.0, 0.5, 0.0, 1.0, p) == pytest.approx(0.3)
    assert resume_path_clearance_m(((-1.0, 0.5),), 1.0, 0.5, 0.0, 1.0, p) == pytest.approx(2.0)
    # A foot on it beyond the horizon is met all the same; one beside it is passed.
    assert resume_path_clearance_m(((20.0, 0.5),), 1.0, 0.5, 0.0, 1.0, p) < 0.1
    assert resume_path_clearance_m(((20.0, 1.7),), 1.0, 0.5, 0.0, 1.0, p) == pytest.approx(1.2)
    # 30° right of it: back left at 10°/s while 10° or more off, a circle of radius
    # v / ω (5.73 m at 1 m/s) about a centre on its left; from 10° on the turn slows and
    # the path leaves the circle outward.
    radius = 1.0 / math.radians(10.0)
    h0, h = math.radians(30.0), math.radians(10.0)
    centre = (radius * math.sin(h0), -radius * math.cos(h0))
    assert resume_path_clearance_m((centre,), 0.0, 0.0, 30.0, 1.0, p) == pytest.approx(
        radius, abs=0.05)
    # A foot on the arc where the heading is 10° off, and one 0.3 m inside it at 20°.
    on_arc = (radius * (math.sin(h0) - math.sin(h)), radius * (math.cos(h) - math.cos(h0)))
    assert resume_path_clearance_m((on_arc,), 0.0, 0.0, 30.0, 1.0, p) < 0.05
    inside = (centre[0] - (radius - 0.3) * math.sin(math.radians(20.0)),
              centre[1] + (radius - 0.3) * math.cos(math.radians(20.0)))
    assert resume_path_clearance_m((inside,), 0.0, 0.0, 30.0, 1.0, p) == pytest.approx(
        0.3, abs=0.02)


def _nearest_along(contact, along, across, heading_deg, length_m=30.0, step_m=0.001):
    """The nearest a straight path comes to ``contact``, by walking it (a check of
    clearing_heading that shares none of its arithmetic)."""
    h = math.radians(heading_deg)
    return min(math.hypot(contact[0] - along - s * math.cos(h),
                          contact[1] - across - s * math.sin(h))
               for s in (k * step_m for k in range(round(length_m / step_m))))


def test_the_heading_flown_past_measured_feet_is_the_least_turn_that_clears_them():
    from companion.control.policy import clearing_heading

    # The geometry first, with no pass-off angle.
    p = PolicyConfig(resume_clearance_m=0.5, min_avoid_deg=0.0)
    # A face across the course 4-5 m ahead, its right end 1 m right of it; the face's
    # heading (Table II) is 40° right, the course 2°.
    feet = ((4.0, -0.4), (4.6, 0.3), (5.1, 1.0))
    heading = clearing_heading(feet, 0.0, 0.0, 2.0, 42.0, p)
    assert 2.0 < heading < 42.0
    off = heading - 2.0  # feet and path in the course's frame
    assert off == round(off)  # whole degrees off the course
    assert min(_nearest_along(f, 0.0, 0.0, off) for f in feet) >= 0.5
    assert min(_nearest_along(f, 0.0, 0.0, off - 1.0) for f in feet) < 0.5
    # Passed on the left, the same on the left.
    mirrored = tuple((a, -r) for a, r in feet)
    assert clearing_heading(mirrored, 0.0, 0.0, 0.0, -40.0, p) == -clearing_heading(
        feet, 0.0, 0.0, 0.0, 40.0, p)
    # Feet beside the course: the course itself; none known, or the rule off: the face's.
    assert clearing_heading(((4.0, -1.5),), 0.0, 0.0, 2.0, 42.0, p) == 2.0
    assert clearing_heading((), 0.0, 0.0, 2.0, 42.0, p) == 42.0
    no_clearance = PolicyConfig(resume_clearance_m=0.0, min_avoid_deg=0.0)
    assert clearing_heading(feet, 0.0, 0.0, 2.0, 42.0, no_clearance) == 42.0
    # No heading up to the face's clears a foot straight ahead at 0.6 m: the face's.
    assert clearing_heading(((0.6, 0.0),), 0.0, 0.0, 0.0, 30.0, p) == 30.0
    # A foot already nearer than the clearance is not to be neared: one abeam is cleared
    # by the course; one 0.1 m ahead and 0.3 m right (bearing 71.6°) by the first whole
    # degree at a right angle to it or beyond (-18.4°).
    assert clearing_heading(((0.0, -0.3),), 0.0, 0.0, 0.0, 30.0, p) == 0.0
    assert clearing_heading(((0.1, 0.3),), 0.0, 0.0, 0.0, -30.0, p) == -19.0
    # Seen from 1 m along and 0.5 m right of the course, the feet need less.
    assert clearing_heading(feet, 1.0, 0.5, 2.0, 42.0, p) < heading

    # Never nearer the course than the pass-off angle (30°): feet that the course itself
    # clears, or a few degrees, still get 30°; feet that need more get what they need.
    p30 = PolicyConfig(resume_clearance_m=0.5, min_avoid_deg=30.0)
    assert clearing_heading(((4.0, -1.5),), 0.0, 0.0, 2.0, 42.0, p30) == 32.0
    assert clearing_heading(feet, 0.0, 0.0, 2.0, 42.0, p30) == 32.0
    # (The floor between feet is sampled as ranging.foot_line samples it: 0.25 m apart.)
    wide = tuple((3.0 + 0.8 * k / 10, -0.4 + 2.4 * k / 10) for k in range(11))
    needed = clearing_heading(wide, 0.0, 0.0, 0.0, 44.0, p)
    assert 30.0 < needed < 44.0
    assert clearing_heading(wide, 0.0, 0.0, 0.0, 44.0, p30) == needed
    # A face's heading at the pass-off angle or nearer is the face's.
    assert clearing_heading(feet, 0.0, 0.0, 0.0, 25.0, p30) == 25.0
