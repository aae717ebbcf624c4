"""Homogeneous geometry: VPs at infinity and parallel segments never divide by zero.

The per-segment geometry runs inside the compiled stages, so it is tested through them:
the segment → VP assignment (a segment's consistency with a VP), the corner search
(intersections of legs) and leg growth.
"""

import numpy as np
import pytest

from companion.vision.corners import CornerParams, find_corners, loose_ends
from companion.vision.geometry import direction_of, point_of, to_pixels
from companion.vision.lines import extend_segments
from companion.vision.vanishing import NONE, V3, assign_segments, detect_layout_vps


def test_consistency_with_a_vp_at_infinity():
    segs = np.array([[10, 0, 10, 50], [30, 0, 31, 50], [0, 0, 50, 0]], float)
    labels, angle = assign_segments(segs, np.array([[0.0, 1.0, 0.0]]))
    assert angle[0] == pytest.approx(0.0, abs=1e-9)
    assert angle[1] == pytest.approx(np.degrees(np.arctan(1 / 50)), rel=1e-6)
    assert labels.tolist() == [0, 0, NONE]  # 1.1° and 0.5 px at its ends: an inlier
    assert angle[2] == pytest.approx(90.0)  # the first VP's angle when none is chosen


def test_consistency_with_a_finite_vp():
    # Both segments lie on lines through (100, 100).
    segs = np.array([[0, 0, 50, 50], [100, 0, 100, 40]], float)
    labels, angle = assign_segments(segs, np.array([[100.0, 100.0, 1.0]]))
    assert angle == pytest.approx([0.0, 0.0], abs=1e-9)
    assert labels.tolist() == [0, 0]


def test_a_segment_is_assigned_to_the_vp_it_points_at_most_closely():
    segs = np.array([[0, 0, 100, 2]], float)  # 1.1° below horizontal
    vps = np.array([[1.0, 0.0, 0.0], [100.0, 2.0, 1.0]])  # x-infinity, and its own line
    labels, angle = assign_segments(segs, vps)
    assert labels.tolist() == [1] and angle[0] == pytest.approx(0.0, abs=1e-9)


def test_zero_length_segment_is_harmless():
    point = np.array([[5, 5, 5, 5]], float)
    labels, angle = assign_segments(point, np.array([[0.0, 1.0, 0.0]]))
    assert labels.tolist() == [NONE] and angle[0] == pytest.approx(90.0)
    room = np.vstack([point, [[100, 100, 100, 300], [300, 100, 300, 300], [0, 50, 200, 60]]])
    layout = detect_layout_vps(room, 640, 480, 320.0)
    assert np.all(np.isfinite(layout.vps))
    assert len(find_corners(room, np.array([NONE, V3, V3, NONE]))) == 0
    assert loose_ends(point, 10.0).tolist() == [[True, True]]
    gray = np.full((480, 640), 128, np.uint8)
    assert np.array_equal(extend_segments(gray, point), point)


def _legs_and_vertical(leg_b):
    """L_s ending at (100, 100), a second leg ``leg_b``, and a vertical leg up from there."""
    return np.array([[0, 100, 100, 100], leg_b, [100, 100, 100, 0]], float)


def test_parallel_legs_meet_at_infinity_not_at_a_corner():
    any_angle = CornerParams(min_leg_angle_deg=0.0)  # only the intersection decides
    labels = np.array([NONE, NONE, V3])
    for leg_b in ([101, 103, 200, 103],    # parallel, 3 px apart: they meet at infinity
                  [102, 100, 200, 100]):   # collinear: the "intersection" is undefined
        corners = find_corners(_legs_and_vertical(leg_b), labels, any_angle)
        assert len(corners) == 0


def test_near_parallel_legs_meet_far_away_without_overflow():
    segs = _legs_and_vertical([101, 103, 200, 103.0001])
    corners = find_corners(segs, np.array([NONE, NONE, V3]), CornerParams(min_leg_angle_deg=0.0))
    assert len(corners) == 0  # they meet ~10⁶ px away, not at the legs' ends
    # The same legs 30° apart make a corner at their meeting point.
    a = np.radians(30.0)
    segs = _legs_and_vertical([100, 100, 100 + 100 * np.cos(a), 100 + 100 * np.sin(a)])
    corners = find_corners(segs, np.array([NONE, NONE, V3]))
    assert corners.points_px[0] == pytest.approx([100, 100], abs=1e-9)


def test_parallel_segments_meet_at_infinity():
    assert to_pixels(np.array([1.0, 0.0, 0.0])) is None
    assert to_pixels(np.array([10.0, 20.0, 2.0])) == pytest.approx([5.0, 10.0])


def test_direction_and_point_are_inverse_including_infinity():
    c = np.array([319.5, 239.5])
    for v in ([400.0, 200.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]):
        v = np.array(v) / np.linalg.norm(v)
        back = point_of(direction_of(v, 500.0, c), 500.0, c)
        assert np.allclose(back, v) or np.allclose(back, -v)
