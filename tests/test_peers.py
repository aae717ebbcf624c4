"""The peer lu-vp-detect through our OpenCV 5 shim (an optional extra; `.ci/run` installs it
with ``pip install --no-deps lu-vp-detect``)."""

import numpy as np
import pytest

from sitl.sample import sample_scene
from sitl.scene import render
from sitl.yud import angular_errors_deg

pytest.importorskip("lu_vp_detect", reason="optional peer: pip install --no-deps lu-vp-detect")


def test_lu_vp_detect_finds_the_rendered_room_frame_through_the_shim():
    from sitl.peers import lu_vp_detector

    scene, cam = sample_scene()
    image, _ = render(scene, cam)
    detect = lu_vp_detector(cam.focal_px, tuple(cam.centre_px))
    vps = detect(image)
    assert vps.shape == (3, 3)
    f, (cx, cy) = cam.focal_px, cam.centre_px
    k_inv = np.linalg.inv(np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]]))
    truth = np.array([k_inv @ cam.vp_of(axis) for axis in np.eye(3)])
    errors = angular_errors_deg(truth, [k_inv @ v for v in vps])
    assert np.median(errors) < 2.0, errors
