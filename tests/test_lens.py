"""Lens distortion: OpenCV's model undone before the line detector (companion.vision.lens)."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from companion.config import Config
from companion.vision.lens import camera_matrix, distort_px, undistort_maps
from companion.vision.pipeline import Pipeline
from sitl.sample import sample_scene
from sitl.scene import Camera, render


def through_lens(image: np.ndarray, focal_px: float, distortion) -> np.ndarray:
    """The pinhole ``image`` as a camera with this lens takes it: each raw pixel reads the
    pinhole pixel OpenCV's model undistorts it to."""
    h, w = image.shape[:2]
    k = camera_matrix(w, h, focal_px)
    coeffs = np.zeros(5)
    coeffs[: len(distortion)] = distortion
    uv = np.stack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)),
                  axis=-1)
    src = cv2.undistortPoints(uv.reshape(-1, 1, 2), k, coeffs, P=k).reshape(h, w, 2)
    return cv2.remap(image, src[..., 0], src[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


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


def test_the_pathtraced_lens_as_opencv_coefficients():
    from sitl.pathtraced import distort_points, opencv_distortion

    cam = Camera(width=640, height=480, hfov_deg=110.0)
    pts = np.array([[0.0, 0.0], [639.0, 479.0], [320.0, 20.0], [50.0, 240.0]])
    for k1 in (0.01, 0.04):
        ours = distort_px(pts, 640, 480, cam.focal_px, opencv_distortion(cam, k1))
        assert np.abs(ours - distort_points(cam, k1, pts)).max() < 0.2
