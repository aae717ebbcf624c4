"""Lens distortion: OpenCV's model undone before the line detector (companion.vision.lens)."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from companion.config import Config
from companion.vision.lens import (
    distort_maps,
    distort_px,
    half_diagonal,
    radial_k,
    undistort_maps,
)
from companion.vision.lines import noise_sigma, to_gray
from companion.vision.pipeline import LENS_FRAMES, Pipeline, RunningLens
from sitl.sample import sample_scene
from sitl.scene import Camera, render, yaw_sweep


def through_lens(image: np.ndarray, focal_px: float, distortion) -> np.ndarray:
    """The pinhole ``image`` as a camera with this lens takes it."""
    h, w = image.shape[:2]
    mx, my = distort_maps(w, h, focal_px, distortion)
    return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def test_the_maps_read_each_pinhole_pixel_where_the_lens_put_it():
    w, h, f, lens = 640, 480, 320.0, (-0.2, 0.05, 0.001, -0.002, 0.0)
    mx, my = cv2.convertMaps(*undistort_maps(w, h, f, lens), cv2.CV_32FC1)
    pts = np.array([[5, 5], [630, 20], [319.5, 239.5], [100, 400], [600, 470]])
    raw = distort_px(pts, w, h, f, lens)
    read = np.stack([mx[pts[:, 1].astype(int), pts[:, 0].astype(int)],
                     my[pts[:, 1].astype(int), pts[:, 0].astype(int)]], axis=1)
    # The centre stays put; a corner moves tens of pixels; the map agrees to its 1/32 px.
    assert np.allclose(raw[2], [319.5, 239.5])
    assert np.hypot(*(raw[0] - pts[0])) > 30
    assert np.allclose(read[[0, 1, 3, 4]], raw[[0, 1, 3, 4]], atol=0.1)


def test_a_prefix_of_the_coefficients_is_the_rest_zero():
    pts = np.array([[10.0, 20.0], [600.0, 400.0]])
    assert np.allclose(distort_px(pts, 640, 480, 300.0, (-0.1,)),
                       distort_px(pts, 640, 480, 300.0, (-0.1, 0, 0, 0, 0)))


def test_a_bent_edge_is_straight_again_in_the_pipeline_picture():
    # A dark band whose edge is a straight line 200 px below the centre, seen through a
    # barrel lens: the edge bows in the frame, and is one straight segment once undone.
    f, lens = 320.0, (-0.2,)
    image = np.full((480, 640), 200, np.uint8)
    image[440:] = 40
    raw = through_lens(image, f, lens)
    rows = [np.flatnonzero(np.diff(raw[:, x].astype(int)) < -60)[0] for x in (40, 320, 600)]
    assert rows[1] - min(rows[0], rows[2]) > 8  # bowed: the ends ride higher than the middle
    cfg = replace(Config(), camera=replace(Config().camera, focal_px=f, distortion=lens))
    pinhole = Pipeline(cfg).pinhole(raw)
    fixed = [np.flatnonzero(np.diff(pinhole[:, x].astype(int)) < -60)[0] for x in (60, 320, 580)]
    assert max(fixed) - min(fixed) <= 2  # two resamplings: a pixel either way


@pytest.mark.parametrize("yaw", [10.0, 22.0])
def test_eta_through_a_wide_lens_is_the_pinhole_eta_once_the_lens_is_given(yaw):
    scene, cam = sample_scene()
    cam = replace(cam, yaw_deg=yaw)
    image, truth = render(scene, cam)
    lens = (-0.15,)
    raw = through_lens(image, cam.focal_px, lens)
    focal_only = replace(Config().camera, focal_px=cam.focal_px)
    bent = Pipeline(replace(Config(), camera=focal_only))(raw)
    undone = Pipeline(replace(Config(), camera=replace(focal_only, distortion=lens)))(raw)
    eta = truth.obstacles[0].eta_deg
    assert bent.eta_deg is not None and undone.eta_deg is not None
    assert abs(bent.eta_deg - eta) > 1.0  # the lens skews η by more than a degree ...
    assert undone.eta_deg == pytest.approx(eta, abs=0.5)  # ... and undone, it is back


def test_positions_in_the_pipeline_picture_map_back_to_where_the_frame_shows_them():
    # An Estimate's pixels are in the picture with the lens undone; the truth of a frame
    # taken through the lens is in the frame. frame_px puts the lens back.
    scene, cam = sample_scene()
    image, truth = render(scene, cam)
    lens = (-0.15,)
    raw = through_lens(image, cam.focal_px, lens)
    cfg = replace(Config(), camera=replace(Config().camera, focal_px=cam.focal_px,
                                           distortion=lens))
    pipe = Pipeline(cfg)
    found = np.asarray(pipe(raw).obstacles[0].corners_px).reshape(-1, 2)
    true_pinhole = np.asarray(truth.obstacles[0].corners_px).reshape(-1, 2)
    true_raw = distort_px(true_pinhole, 640, 480, cam.focal_px, lens)

    def miss(points, truth_points):
        return np.linalg.norm(points[:, None] - truth_points[None], axis=2).min(axis=1)

    back = pipe.frame_px(found, 640, 480)
    assert miss(found, true_raw).max() > 5.0  # the lens moves a corner by more than 5 px
    assert np.allclose(miss(back, true_raw), miss(found, true_pinhole), atol=1.0)
    plain = Pipeline(replace(cfg, camera=replace(cfg.camera, distortion=(0.0,))))
    plain(image)
    assert np.array_equal(plain.frame_px(found, 640, 480), found)  # a pinhole: as they are


def test_the_pathtraced_lens_as_opencv_coefficients():
    from sitl.pathtraced import distort_points, opencv_distortion

    cam = Camera(width=640, height=480, hfov_deg=110.0)
    pts = np.array([[0.0, 0.0], [639.0, 479.0], [320.0, 20.0], [50.0, 240.0]])
    for k1 in (0.01, 0.04):
        ours = distort_px(pts, 640, 480, cam.focal_px, opencv_distortion(cam, k1))
        assert np.abs(ours - distort_points(cam, k1, pts)).max() < 0.2


def _sweep_through_lens(distortion, frames=12):
    """A yaw sweep past the sample's rotated box, each frame taken through ``distortion``
    (None: a pinhole): (frames, truths, focal length)."""
    scene, cam = sample_scene()
    images, truths = [], []
    for c in yaw_sweep(cam, 4.0, 20.0, frames):
        image, truth = render(scene, c)
        images.append(through_lens(image, c.focal_px, distortion) if distortion else image)
        truths.append(truth)
    return images, truths, cam.focal_px


def test_a_video_learns_its_lens_on_its_first_frames_and_then_undoes_it():
    lens = (-0.1,)
    images, truths, focal = _sweep_through_lens(lens)
    cfg = replace(Config(), camera=replace(Config().camera, focal_px=focal))
    learnt = Pipeline(cfg)
    pinhole = Pipeline(replace(cfg, camera=replace(cfg.camera, distortion=(0.0,))))
    for k, image in enumerate(images):
        ests = learnt(image), pinhole(image)
        assert (learnt.running_lens.k is None) == (k < LENS_FRAMES - 1)
    # The learnt coefficient is the lens's, on the half-diagonal: k1 (r / f)².
    true_k = lens[0] * (half_diagonal(640, 480) / focal) ** 2
    assert learnt.running_lens.k == pytest.approx(true_k, abs=0.02)
    assert pinhole.running_lens.k is None  # a lens given as a pinhole is not estimated
    # After it, η is the pinhole's again; a pipeline told the lens is a pinhole is off.
    eta = truths[-1].obstacles[0].eta_deg
    learnt_eta, pinhole_eta = ests[0].eta_deg, ests[1].eta_deg
    assert learnt_eta == pytest.approx(eta, abs=0.5)
    assert abs(pinhole_eta - eta) > 1.0


def test_a_pinhole_video_learns_that_it_is_one():
    images, _, focal = _sweep_through_lens(None, frames=LENS_FRAMES)
    pipe = Pipeline(replace(Config(), camera=replace(Config().camera, focal_px=focal)))
    for image in images:
        pipe(image)
    assert pipe.running_lens.k == 0.0
    assert pipe.pinhole(images[0]) is images[0]  # nothing undone, nothing copied


def test_a_frame_without_a_room_says_nothing_about_the_lens():
    blank = np.full((480, 640), 128, np.uint8)
    assert radial_k(np.empty((0, 4)), 640, 480, 320.0) is None
    pipe = Pipeline()
    pipe(blank)
    assert pipe.running_lens.estimates_k == ()


def test_the_video_lens_is_the_median_of_its_first_frames_and_a_weak_one_is_a_pinhole():
    lens = RunningLens()
    for k in (-0.05, -0.06, 0.4, -0.05, -0.3, -0.04, -0.05, -0.06, -0.05):
        assert lens.k is None  # not before LENS_FRAMES estimates
        lens = lens.add(k)
    assert lens.settled and lens.k == pytest.approx(-0.05)  # two wild frames outvoted
    weak = RunningLens((-0.02,) * LENS_FRAMES)
    assert weak.k == 0.0  # within the estimate's own bias: left alone


def test_a_lens_without_its_focal_length_is_refused():
    with pytest.raises(ValueError, match="needs camera.focal_px"):
        Pipeline(replace(Config(), camera=replace(Config().camera, distortion=(-0.1,))))
    Pipeline(replace(Config(), camera=replace(Config().camera, distortion=(0.0,))))  # pinhole


def test_the_noise_the_step_test_measures_against_is_the_noise_of_the_frame_as_captured():
    # Undoing a lens resamples the frame: each pixel a blend of its neighbours, which hides
    # about a third of the noise from the estimator (it reads fine detail) but little of it
    # from a step averaged along a segment. So the noise is measured before the remap.
    rng = np.random.default_rng(5)
    frame = np.clip(128 + rng.normal(0.0, 4.0, (480, 640)), 0, 255).astype(np.uint8)
    frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    cfg = replace(Config(), camera=replace(Config().camera, focal_px=320.0))
    pinhole = Pipeline(replace(cfg, camera=replace(cfg.camera, distortion=(0.0,))))(frame)
    undone = Pipeline(replace(cfg, camera=replace(cfg.camera, distortion=(-0.05,))))
    bent = undone(frame)
    assert pinhole.noise_sigma == pytest.approx(4.0, rel=0.05)
    assert bent.noise_sigma == pinhole.noise_sigma
    remapped = noise_sigma(to_gray(undone.pinhole(frame)))  # what the old code measured
    assert remapped < 0.8 * bent.noise_sigma
