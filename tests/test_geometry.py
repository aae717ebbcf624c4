"""Homogeneous geometry: VPs at infinity and parallel segments never divide by zero."""

import numpy as np
import pytest

from companion.vision.geometry import (
    direction_of,
    horizon_line,
    intersect,
    point_of,
    segment_lines,
    to_pixels,
    vp_consistency,
)


def test_parallel_segments_meet_at_infinity():
    lines = segment_lines(np.array([[0, 0, 10, 0], [0, 5, 10, 5]]))
    p = intersect(lines[0], lines[1])
    assert p[2] == pytest.approx(0.0, abs=1e-12)
    assert abs(p[0]) == pytest.approx(1.0)  # the x direction
    assert to_pixels(p) is None


def test_near_parallel_segments_meet_far_away_without_overflow():
    lines = segment_lines(np.array([[0, 0, 100, 0], [0, 5, 100, 5.0001]]))
    p = intersect(lines[0], lines[1])
    assert np.all(np.isfinite(p))
    x = to_pixels(p)
    assert x is not None and abs(x[0]) > 1e6


def test_intersection_of_crossing_segments():
    lines = segment_lines(np.array([[0, 0, 10, 10], [0, 10, 10, 0]]))
    assert to_pixels(intersect(lines[0], lines[1])) == pytest.approx([5.0, 5.0])


def test_consistency_with_a_vp_at_infinity():
    segs = np.array([[10, 0, 10, 50], [30, 0, 31, 50], [0, 0, 50, 0]])
    angle, residual = vp_consistency(segs, np.array([0.0, 1.0, 0.0]))
    assert angle[0] == pytest.approx(0.0, abs=1e-9)
    assert angle[1] == pytest.approx(np.degrees(np.arctan(1 / 50)), rel=1e-6)
    assert angle[2] == pytest.approx(90.0)
    assert residual[1] == pytest.approx(np.sin(np.arctan(1 / 50)) * np.hypot(1, 50) / 2)


def test_consistency_with_a_finite_vp():
    # Both segments lie on lines through (100, 100).
    segs = np.array([[0, 0, 50, 50], [100, 0, 100, 40]])
    angle, residual = vp_consistency(segs, np.array([100.0, 100.0, 1.0]))
    assert angle == pytest.approx([0.0, 0.0], abs=1e-9)
    assert residual == pytest.approx([0.0, 0.0], abs=1e-9)


def test_zero_length_segment_is_harmless():
    angle, _ = vp_consistency(np.array([[5, 5, 5, 5]]), np.array([0.0, 1.0, 0.0]))
    assert angle[0] == pytest.approx(90.0)
    assert np.all(np.isfinite(segment_lines(np.array([[5, 5, 5, 5]]))))


def test_direction_and_point_are_inverse_including_infinity():
    c = np.array([319.5, 239.5])
    for v in ([400.0, 200.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]):
        v = np.array(v) / np.linalg.norm(v)
        back = point_of(direction_of(v, 500.0, c), 500.0, c)
        assert np.allclose(back, v) or np.allclose(back, -v)


def test_horizon_of_a_level_camera_is_the_centre_row():
    c = np.array([319.5, 239.5])
    h = horizon_line(np.array([0.0, 1.0, 0.0]), 320.0, c)
    assert h @ [0.0, 239.5, 1.0] == pytest.approx(0.0, abs=1e-9)
    assert h @ [600.0, 239.5, 1.0] == pytest.approx(0.0, abs=1e-9)
    assert abs(h @ [0.0, 249.5, 1.0]) == pytest.approx(10.0)
