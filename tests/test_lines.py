"""Segment detection (a-contrario validation, the step test against the frame's noise) and
growing toward junctions (companion.vision.lines)."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from companion.config import Config
from companion.report import LEGEND, annotate
from companion.vision.lines import (
    QUANTISATION_SIGMA,
    edge_step_z,
    extend_segments,
    make_detector,
    noise_sigma,
    refine_segments,
)
from companion.vision.pipeline import Pipeline
from companion.vision.vanishing import NONE, V1


def _rectangle(noise=3.0, seed=0):
    # A dark rectangle on a light background: its top edge runs along y = 59.5 from
    # x = 79.5 to x = 239.5 (pixel 60 is the first dark row, 80 the first dark column).
    rng = np.random.default_rng(seed)
    frame = np.full((240, 320), 180.0)
    frame[60:180, 80:240] = 60.0
    frame += rng.normal(0.0, noise, frame.shape)
    return np.clip(frame, 0, 255).astype(np.uint8)


def _noisy_step(seed=0):
    # Sensor noise (σ 14 grey levels, lightly smoothed) over one vertical step edge at x = 159.5.
    rng = np.random.default_rng(seed)
    frame = rng.normal(128.0, 14.0, (240, 320))
    frame[:, 160:] += 60.0
    return cv2.GaussianBlur(np.clip(frame, 0, 255).astype(np.uint8), (3, 3), 0.8)


def test_validation_flags_chance_segments_and_keeps_the_edge():
    frame = _noisy_step()
    segments, validated = make_detector("edlines", 8.0, 20.0, validate=True)(frame)
    unflagged, every = make_detector("edlines", 8.0, 20.0)(frame)
    assert np.array_equal(segments, unflagged) and every.all()  # one detection, flags added
    on_edge = (np.abs(segments[:, 0] - 159.5) < 2) & (np.abs(segments[:, 2] - 159.5) < 2)
    lengths = np.hypot(*(segments[:, 2:] - segments[:, :2]).T)
    assert (lengths[on_edge & validated] > 200).any()  # the real edge, whole, validated
    # Noise makes dozens of short segments; a handful at most pass the test.
    assert len(segments) >= 30
    assert np.count_nonzero(validated) <= len(segments) / 5


def test_corners_are_built_from_validated_segments_and_the_layout_from_all():
    frame = cv2.cvtColor(_noisy_step(), cv2.COLOR_GRAY2BGR)
    cfg = Config()
    pipeline = Pipeline(replace(cfg, vision=replace(cfg.vision, validate_segments=True)))
    every = pipeline.segments(frame)
    est = pipeline(frame)
    assert len(every) >= 30  # the layout's input: every segment
    assert 1 <= len(est.segments) <= len(every) / 5  # the corners': validated ones


@pytest.mark.parametrize("sigma", [2.0, 5.0, 10.0])
def test_the_noise_estimate_measures_the_noise_not_the_shading(sigma):
    rng = np.random.default_rng(int(sigma))
    shading = np.linspace(40.0, 200.0, 320)[None, :] + np.linspace(0.0, 30.0, 240)[:, None]
    frame = np.clip(shading + rng.normal(0.0, sigma, (240, 320)), 0, 255).astype(np.uint8)
    assert noise_sigma(frame) == pytest.approx(sigma, rel=0.1)


def test_a_plain_frame_has_the_noise_of_rounding_alone():
    assert noise_sigma(np.full((120, 160), 77, np.uint8)) == QUANTISATION_SIGMA


def _step(contrast, noise, seed=0):
    # A horizontal step edge at y = 119.5 of `contrast` grey levels under white noise.
    rng = np.random.default_rng(seed)
    frame = np.full((240, 320), 100.0)
    frame[120:] += contrast
    return np.clip(frame + rng.normal(0.0, noise, frame.shape), 0, 255).astype(np.uint8)


def test_the_step_test_weighs_contrast_against_length():
    faint, strong = _step(6.0, 4.0), _step(40.0, 4.0)
    long_edge, short_edge = [[20.0, 119.5, 300.0, 119.5]], [[150.0, 119.5, 162.0, 119.5]]
    off_edge = [[20.0, 60.5, 300.0, 60.5]]
    z = {name: edge_step_z(frame, np.array(seg), noise_sigma(frame))[0]
         for name, frame, seg in [("faint long", faint, long_edge),
                                  ("faint short", faint, short_edge),
                                  ("strong short", strong, short_edge),
                                  ("plain wall", strong, off_edge)]}
    # 64 stations average the noise down; 6 do not (the median's standard error is
    # 1.25 σ / √m: a 6-level step is 9.6 of them over 64 stations, 2.9 over 6).
    assert z["faint long"] > 6.0 > z["faint short"]
    assert z["strong short"] > 6.0 > z["plain wall"]


def test_the_step_test_keeps_the_edge_and_drops_chance_segments():
    frame = _noisy_step()
    segments, _ = make_detector("edlines", 8.0, 20.0)(frame)
    z = edge_step_z(frame, segments, noise_sigma(frame))
    on_edge = (np.abs(segments[:, 0] - 159.5) < 2) & (np.abs(segments[:, 2] - 159.5) < 2)
    assert on_edge.any() and (z[on_edge] > 30).all()
    # Dozens of chance segments, fitted to chains of noise pixels; few stand out of it.
    chance = z[~on_edge]
    assert len(chance) >= 30
    assert np.count_nonzero(chance >= Config().vision.min_step_z) <= 0.1 * len(chance)


def test_the_noise_estimate_and_the_step_test_do_not_depend_on_handedness():
    # A mirrored frame is the same scene: the same σ, and the same z for each segment
    # mirrored with it. Every other column counted from the left is the even columns of
    # one and the odd ones of the other; and the median of an even number of stations,
    # whose differences the mirror negates, must not pick a different one of the two.
    rng = np.random.default_rng(4)
    texture = cv2.GaussianBlur(rng.normal(0.0, 25.0, (240, 320)), (0, 0), 1.5)
    frame = np.clip(110.0 + texture + rng.normal(0.0, 3.0, (240, 320)), 0, 255).astype(np.uint8)
    frame[:, 170:] = np.clip(frame[:, 170:].astype(int) + 40, 0, 255).astype(np.uint8)
    mirrored = np.ascontiguousarray(frame[:, ::-1])
    assert noise_sigma(mirrored) == noise_sigma(frame)
    segments = np.column_stack([rng.uniform(0, 319, 60), rng.uniform(0, 239, 60),
                                rng.uniform(0, 319, 60), rng.uniform(0, 239, 60)])
    segments = np.vstack([segments, [[169.5, 20.0, 169.5, 27.5], [169.5, 30.0, 169.5, 200.0]]])
    flipped = segments.copy()
    flipped[:, [0, 2]] = 319.0 - segments[:, [0, 2]]
    sigma = noise_sigma(frame)
    z = edge_step_z(frame, segments, sigma)
    assert edge_step_z(mirrored, flipped, sigma) == pytest.approx(z, abs=1e-9)
    assert z[-1] > 30.0  # the step itself


def test_only_unassigned_segments_are_put_to_the_step_test():
    frame = _rectangle(noise=3.0)
    segments = np.array([[90.0, 59.5, 230.0, 59.5],     # the rectangle's top edge
                         [90.0, 100.5, 230.0, 100.5],   # inside it: no edge
                         [90.0, 30.5, 230.0, 30.5]])    # above it: no edge, but V1's
    labels = np.array([NONE, NONE, V1])
    sigma = noise_sigma(frame)
    kept, kept_labels, dropped = Pipeline(Config())._drop_noise(frame, sigma, segments, labels)
    assert np.array_equal(kept, segments[[0, 2]]) and list(kept_labels) == [NONE, V1]
    assert np.array_equal(dropped, segments[[1]])  # for the annotated video to draw
    cfg = Config()
    off = Pipeline(replace(cfg, vision=replace(cfg.vision, min_step_z=0.0)))
    kept, _, dropped = off._drop_noise(frame, sigma, segments, labels)
    assert np.array_equal(kept, segments) and len(dropped) == 0


def test_the_annotated_frame_draws_the_segments_dropped_as_noise():
    frame = cv2.cvtColor(_noisy_step(), cv2.COLOR_GRAY2BGR)
    est = Pipeline(Config())(frame)
    assert len(est.noise_segments) >= 10  # the chance segments on the noise
    blank = np.zeros_like(frame)
    with_noise = annotate(blank, est)
    without = annotate(blank, replace(est, noise_segments=est.noise_segments[:0]))
    drawn = np.any(with_noise != without, axis=2)
    assert drawn.sum() > 100
    px = with_noise[drawn].astype(int)  # dark grey, anti-aliased, save where others cross
    grey = (px.max(axis=1) - px.min(axis=1) <= 2) & (px.max(axis=1) <= 90)
    assert grey.mean() > 0.9
    assert "noise" in [name for name, _ in LEGEND]


def test_a_segment_short_of_both_corners_grows_to_them():
    seg = np.array([[100.0, 59.5, 220.0, 59.5]])
    out = extend_segments(_rectangle(), seg, max_px=24.0, step_px=2.0)
    assert out[0, 1] == pytest.approx(59.5) and out[0, 3] == pytest.approx(59.5)
    assert out[0, 0] == pytest.approx(79.5, abs=2.5)
    assert out[0, 2] == pytest.approx(239.5, abs=2.5)


def test_growth_stops_at_the_corner_and_at_max_px():
    at_corner = np.array([[80.0, 59.5, 239.0, 59.5]])
    assert np.allclose(extend_segments(_rectangle(), at_corner), at_corner, atol=2.5)
    far = np.array([[150.0, 59.5, 170.0, 59.5]])  # 70 px from either corner
    out = extend_segments(_rectangle(), far, max_px=24.0, step_px=2.0)
    assert out[0, 0] == pytest.approx(126.0) and out[0, 2] == pytest.approx(194.0)


def test_the_step_must_keep_its_sign():
    # The left half of the edge is dark-below, the right half dark-above: a segment on
    # the left half must not grow into the right half.
    frame = np.full((100, 200), 180, np.uint8)
    frame[50:, :100] = 60
    frame[:50, 100:] = 60
    seg = np.array([[40.0, 49.5, 90.0, 49.5]])
    out = extend_segments(frame, seg, max_px=30.0, step_px=2.0)
    assert out[0, 2] <= 100.0


def test_no_contrast_no_growth_and_shapes_kept():
    flat = np.full((120, 160), 90, np.uint8)
    segs = np.array([[20.0, 30.0, 60.0, 30.0], [50.0, 10.0, 50.0, 100.0]])
    assert np.array_equal(extend_segments(flat, segs), segs)
    assert extend_segments(flat, np.empty((0, 4))).shape == (0, 4)


def test_a_vertical_side_grows_to_both_corners():
    seg = np.array([[79.5, 70.0, 79.5, 170.0]])
    out = extend_segments(_rectangle(), seg, max_px=30.0, step_px=2.0)
    assert out[0, 1] == pytest.approx(59.5, abs=2.5)
    assert out[0, 3] == pytest.approx(179.5, abs=2.5)


def test_growth_stops_at_the_frame_border():
    frame = _rectangle()
    frame[60:180, 80:] = frame[60:180, 80:240].mean()  # the rectangle reaches the right border
    seg = np.array([[260.0, 59.5, 300.0, 59.5]])
    out = extend_segments(frame, seg, max_px=40.0, step_px=2.0)
    assert 316.0 <= out[0, 2] <= 319.0


def test_zero_growth_leaves_segments_alone():
    seg = np.array([[100.0, 59.5, 220.0, 59.5]])
    assert np.array_equal(extend_segments(_rectangle(), seg, max_px=0.0), seg)


def test_only_the_ends_allowed_to_grow_do():
    seg = np.array([[100.0, 59.5, 220.0, 59.5]])
    out = extend_segments(_rectangle(), seg, max_px=24.0, step_px=2.0,
                          ends=np.array([[False, True]]))
    assert out[0, 0] == 100.0
    assert out[0, 2] == pytest.approx(239.5, abs=2.5)


def test_loose_ends_are_those_that_meet_no_other_segment():
    from companion.vision.corners import loose_ends

    segs = np.array([[0.0, 0.0, 50.0, 0.0],     # its right end meets the next one's left end
                     [53.0, 4.0, 90.0, 30.0],
                     [200.0, 200.0, 260.0, 200.0]])  # alone
    assert loose_ends(segs, 10.0).tolist() == [[True, False], [False, True], [True, True]]
    assert loose_ends(segs, 4.0).tolist() == [[True, True], [True, True], [True, True]]


def test_an_occluding_edge_grows_across_a_change_of_background_and_stops_at_its_corner():
    # A dark box (columns 160–279, rows 60–199) in front of a wall (180) that meets a
    # skirting board (70) at row 120 and the floor (110) at row 130. On the left edge of
    # the box the step across flips size twice as the background changes; the box's
    # side of the edge stays the same, so the edge goes on to the box's bottom corner.
    rng = np.random.default_rng(1)
    frame = np.full((240, 320), 180.0)
    frame[120:130] = 70.0
    frame[130:] = 110.0
    frame[60:200, 160:280] = 40.0
    frame = np.clip(frame + rng.normal(0.0, 2.0, frame.shape), 0, 255).astype(np.uint8)
    seg = np.array([[159.5, 70.0, 159.5, 110.0]])
    out = extend_segments(frame, seg, max_px=100.0, step_px=2.0)
    assert out[0, 0] == pytest.approx(159.5) and out[0, 2] == pytest.approx(159.5)
    assert out[0, 1] == pytest.approx(59.5, abs=2.5)  # the top corner, against the wall
    assert out[0, 3] == pytest.approx(199.5, abs=2.5)  # the bottom corner, on the floor


def test_a_room_line_ending_on_an_obstacle_edge_does_not_pin_it():
    from companion.vision.corners import loose_ends

    segs = np.array([[100.0, 50.0, 100.0, 150.0],    # an obstacle's vertical edge
                     [102.0, 152.0, 300.0, 152.0]])  # a skirting line hidden behind it
    assert loose_ends(segs, 10.0).tolist() == [[True, False], [False, True]]
    # Only the obstacle's edge can make a Table-I corner: the T-junction is not its corner.
    among = np.array([True, False])
    assert loose_ends(segs, 10.0, among=among).tolist() == [[True, True], [False, False]]


def _across_edge(x, y, angle_deg, offset_px):
    """Signed distance in pixels of (x, y) from the edge of :func:`_tilted_edge` (positive
    on its dark side)."""
    t = np.radians(angle_deg)
    return -(x - 160.0 - offset_px) * np.sin(t) + (y - 120.0) * np.cos(t)


def _distance_to_edge(points, angle_deg, offset_px):
    return _across_edge(points[:, 0], points[:, 1], angle_deg, offset_px)


def _tilted_edge(angle_deg, offset_px, noise=2.0, seed=0, scale=8):
    """A straight step edge through (160 + offset_px, 120) at ``angle_deg`` from the x
    axis, dark below it, drawn at ``scale``× and area-averaged to 320×240 (pixel centres
    at whole coordinates), plus sensor noise: the line the refinement should find."""
    h, w = 240 * scale, 320 * scale
    ys, xs = np.mgrid[0:h, 0:w]
    x = (xs + 0.5) / scale - 0.5
    y = (ys + 0.5) / scale - 0.5
    big = np.where(_across_edge(x, y, angle_deg, offset_px) > 0, 60.0, 180.0).astype(
        np.float32)
    frame = cv2.resize(big, (320, 240), interpolation=cv2.INTER_AREA)
    frame += np.random.default_rng(seed).normal(0.0, noise, frame.shape)
    return np.clip(frame, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("angle_deg", [7.0, 38.0, 81.0])
def test_refinement_moves_a_segment_onto_its_edge(angle_deg):
    offset = 0.3
    frame = _tilted_edge(angle_deg, offset)
    t = np.radians(angle_deg)
    u = np.array([np.cos(t), np.sin(t)])
    n = np.array([-np.sin(t), np.cos(t)])
    centre = np.array([160.0 + offset, 120.0])
    # A detector's segment, 60 px long, 0.8 px off the edge at one end and 0.2 px at the
    # other: 1° out.
    a = centre - 30 * u + 0.8 * n
    b = centre + 30 * u - 0.2 * n
    seg = np.array([[*a, *b]])
    before = np.abs(_distance_to_edge(seg.reshape(2, 2), angle_deg, offset))
    out = refine_segments(frame, seg)
    after = np.abs(_distance_to_edge(out.reshape(2, 2), angle_deg, offset))
    assert before.max() > 0.7
    assert after.max() < 0.1
    # The ends keep their places along the line.
    along = (out.reshape(2, 2) - seg.reshape(2, 2)) @ u
    assert np.abs(along).max() < 0.05


def test_refinement_leaves_short_segments_and_segments_with_no_edge_alone():
    frame = _tilted_edge(20.0, 0.0)
    short = np.array([[150.0, 117.0, 160.0, 121.0]])  # 11 px: too few stations
    assert np.array_equal(refine_segments(frame, short), short)
    flat = np.array([[20.0, 200.0, 120.0, 200.0]])  # far from the edge, on flat grey
    assert np.array_equal(refine_segments(frame, flat), flat)
    # A segment 4 px from the edge: the peak in the window is not its edge's.
    t = np.radians(20.0)
    n = np.array([-np.sin(t), np.cos(t)])
    u = np.array([np.cos(t), np.sin(t)])
    a, b = np.array([160.0, 120.0]) - 30 * u + 4 * n, np.array([160.0, 120.0]) + 30 * u + 4 * n
    off = np.array([[*a, *b]])
    assert np.array_equal(refine_segments(frame, off), off)


def test_the_pipeline_refines_its_segments_when_asked():
    frame = cv2.cvtColor(_tilted_edge(12.0, 0.4), cv2.COLOR_GRAY2BGR)
    cfg = Config()
    plain = Pipeline(cfg).segments(frame)
    refined = Pipeline(replace(cfg, vision=replace(cfg.vision, refine_segments=True))).segments(
        frame)
    assert len(plain) == len(refined) >= 1
    on_edge = np.abs(_distance_to_edge(refined.reshape(-1, 2), 12.0, 0.4))
    was = np.abs(_distance_to_edge(plain.reshape(-1, 2), 12.0, 0.4))
    assert on_edge.max() < 0.15
    assert not np.array_equal(plain, refined)
    assert on_edge.max() <= was.max()
