"""Tracking one obstacle across frames (companion/vision/tracking.py)."""

import pytest

from companion.vision.tracking import TrackParams, update_track, wrap90


def _run(frames, params=None):
    track, out = None, []
    for eta, room in frames:
        track, tracked = update_track(track, eta, room, params)
        out.append(tracked)
    return out


def test_wrap90_folds_into_the_half_open_quarter():
    assert wrap90(44.0) == 44.0
    assert wrap90(46.0) == -44.0
    assert wrap90(-45.0) == 45.0
    assert wrap90(135.0) == 45.0
    assert wrap90(-100.0) == pytest.approx(-10.0)


def test_a_one_frame_detection_is_not_reported():
    assert _run([(20.0, 3.0), (None, 3.0), (None, 3.0)]) == [None, None, None]


def test_a_first_frame_two_corner_pairs_agree_on_is_reported_but_not_bridged():
    # Two corners of one frame whose legs give the same OVPs are two measurements of them:
    # the detection is reported at once. The track itself still needs a second frame, so a
    # drop-out after that one frame is not predicted through as a confirmed track's is.
    track, first = update_track(None, 20.0, 3.0, pairs=2)
    assert first == pytest.approx(20.0)
    track, after = update_track(track, None, 3.0)
    assert after is None and not track.confirmed(TrackParams())
    assert update_track(None, 20.0, 3.0, pairs=1)[1] is None
    assert update_track(None, 20.0, 3.0, TrackParams(report_pairs=0), pairs=5)[1] is None


def test_a_detection_waits_one_frame_of_noise_or_drop_out_for_its_second():
    # Track initiation by M-of-N logic (2 of 3): the frame between two consistent ones may
    # miss the obstacle or read it 15° off without replacing the first.
    for between in [(None, 3.0), (35.0, 3.0)]:
        out = _run([(20.0, 3.0), between, (20.4, 3.0), (20.2, 3.0)])
        assert out[:2] == [None, None]
        assert out[2] == pytest.approx(20.2) and out[3] == pytest.approx(20.2)
    # Two frames between are too many: the third consistent frame starts afresh.
    assert _run([(20.0, 3.0), (None, 3.0), (35.0, 3.0), (20.4, 3.0)]) == [None] * 4
    # A confirm_window of confirm_hits: consistent frames in a row only.
    assert _run([(20.0, 3.0), (None, 3.0), (20.4, 3.0)], TrackParams(confirm_window=2)) == [
        None] * 3


def test_confirmed_after_two_consistent_frames():
    out = _run([(20.0, 3.0), (20.4, 3.0), (20.2, 3.0)])
    assert out[0] is None
    # The face angle to the room (17°, then 17.4°) is smoothed to 17.2°, carried by the room.
    assert out[1] == pytest.approx(20.2) and out[2] == pytest.approx(20.2)


def test_eq9_flip_near_45_degrees_is_held():
    # A face 44–46° to the line of sight: the frame's M jumps between the two OVPs, 90°
    # apart, and η changes sign. The track keeps following one of them.
    frames = [(44.0, 0.0), (44.5, 0.0), (-44.2, 0.0), (44.8, 0.0), (-43.9, 0.0)]
    out = _run(frames)
    assert all(43.0 <= eta <= 47.0 for eta in out[1:])  # one OVP, never the other at −45°


def test_the_other_ovp_takes_over_once_clearly_nearer_the_centre():
    # The vehicle yaws 5° a frame: the room's η and the obstacle's move together.
    frames = [(40.0 - 5 * k, -5.0 * k) for k in range(8)]
    frames = [((e + 45.0) % 90.0 - 45.0, r) for e, r in frames]  # what eq. 9 reports
    out = _run(frames)
    assert out[1] == pytest.approx(35.0)
    assert out[-1] == pytest.approx(5.0)  # 40 − 35: followed through 0° without a jump


def test_one_frames_noise_moves_the_tracked_eta_by_the_smoothing_share_of_it():
    # The vehicle yaws 2° a frame; the room's η follows it exactly, the obstacle's η
    # (a fit to a few short edges) is 30° − yaw, ±1.5° of noise alternating frame to frame.
    yaw = [2.0 * k for k in range(12)]
    frames = [(30.0 - y + (1.5 if k % 2 else -1.5), -y) for k, y in enumerate(yaw)]
    out = _run(frames)
    late = [abs(out[k] - (30.0 - yaw[k])) for k in range(6, 12)]
    assert max(late) < 1.0  # per frame: 1.5° on every frame


def test_a_dropout_is_bridged_by_the_room_and_then_the_track_ends():
    p = TrackParams(max_missed=2)
    frames = [(20.0, 0.0), (20.0, 0.0), (None, 4.0), (None, 6.0), (None, 6.0)]
    out = _run(frames, p)
    assert out[2] == pytest.approx(24.0) and out[3] == pytest.approx(26.0)
    assert out[4] is None


def test_a_dropout_without_the_room_holds_the_last_eta():
    out = _run([(20.0, 0.0), (20.0, 0.0), (None, None)])
    assert out[2] == pytest.approx(20.0)


def test_a_false_alarm_beside_a_confirmed_track_does_not_move_it():
    frames = [(20.0, 0.0), (20.0, 0.0), (-30.0, 0.0), (20.2, 0.0)]
    out = _run(frames)
    assert out[2] == pytest.approx(20.0)  # predicted, not −30
    assert out[3] == pytest.approx(20.1)  # 20.2 moves the face angle halfway


def test_another_obstacle_takes_over_when_the_track_runs_out():
    p = TrackParams(max_missed=1)
    frames = [(20.0, 0.0), (20.0, 0.0), (None, 0.0), (-30.0, 0.0), (-30.0, 0.0), (-30.5, 0.0)]
    out = _run(frames, p)
    assert out[2] == pytest.approx(20.0)
    assert out[3] is None  # the old track ended; the newcomer starts unconfirmed
    assert out[4] == pytest.approx(-30.0) and out[5] == pytest.approx(-30.25)


def test_two_frames_agreeing_on_another_face_angle_take_over_from_a_coasting_track():
    # A track confirmed on two wrong frames (20°) meets the obstacle (−30°, 50° away, far
    # outside the gate): it is predicted on, but the newcomer waits beside it, and its
    # second frame, even after a frame without a detection, replaces it at once rather
    # than after the track's max_missed frames of coasting.
    out = _run([(20.0, 0.0), (20.0, 0.0), (-30.0, 0.0), (-30.0, 0.0), (-30.5, 0.0)])
    assert out[2] == pytest.approx(20.0)
    assert out[3] == pytest.approx(-30.0) and out[4] == pytest.approx(-30.25)
    out = _run([(20.0, 0.0), (20.0, 0.0), (-30.0, 0.0), (None, 2.0), (-28.0, 2.0)])
    assert out[3] == pytest.approx(22.0)  # still the old track, carried by the room
    assert out[4] == pytest.approx(-28.0)


def test_a_piece_seen_beside_the_reported_one_is_confirmed_when_it_comes_to_drive_eta():
    # Two pieces in view: the frames' best-supported obstacle is the one at 20° for two
    # frames, with the one at −30° beside it, then the −30° one. Its track was measured in
    # the frames before, so it is reported at once, where a track of the frame's obstacle
    # alone would predict the 20° piece on while the newcomer waits for its second frame.
    track, out = None, []
    for eta, others in [(20.0, (-30.0,)), (20.2, (-30.4,)), (-30.2, (20.1,)), (-30.0, ())]:
        track, tracked = update_track(track, eta, 0.0, others_deg=others)
        out.append(tracked)
    assert out[1] == pytest.approx(20.1)
    assert out[2] == pytest.approx(-30.2, abs=0.11) and out[3] == pytest.approx(-30.1, abs=0.11)
    # Without the piece beside it, the same frames coast the 20° track one frame.
    assert _run([(20.0, 0.0), (20.2, 0.0), (-30.2, 0.0), (-30.0, 0.0)])[2] == pytest.approx(20.1)


def test_a_confirmed_track_measured_beside_the_frames_obstacle_is_not_predicted():
    # The reported piece is read beside a newcomer (a false alarm, seen once): the track is
    # measured, so its η follows the measurement, not the room's prediction.
    track = None
    for eta in (20.0, 20.0):
        track, _ = update_track(track, eta, 0.0)
    track, tracked = update_track(track, -30.0, 0.0, others_deg=(22.0,))
    assert tracked == pytest.approx(21.0)  # halfway to 22°; predicted it would be 20°
    assert track.missed == 0


def test_a_second_reading_of_one_obstacle_does_not_split_its_track():
    # Two hypotheses of one box in a frame, 2° apart: one track, which the next frame's
    # reading renews and reports, rather than a second track that the reading confirms.
    track, _ = update_track(None, 20.0, 0.0)
    track, _ = update_track(track, 20.4, 0.0, others_deg=(18.0,))
    assert track.beside == ()
    track, tracked = update_track(track, 19.0, 0.0)
    assert tracked == pytest.approx(19.6) and track.hits == 3
