import numpy as np
import pytest
from helpers.ground_station import Client

from sitl.sample import sample_scene
from sitl.scene import write_video, yaw_sweep


@pytest.fixture(scope="session")
def sample_video(tmp_path_factory):
    """A short real MP4 (OpenCV-encoded) of the sample scene, with its truth file."""
    d = tmp_path_factory.mktemp("video")
    scene, cam = sample_scene()
    path, truth = d / "turn.mp4", d / "turn.truth.jsonl"
    write_video(scene, yaw_sweep(cam, 5.0, 25.0, 6), path, 10.0, truth)
    return path, truth


@pytest.fixture(scope="session")
def blank_video(tmp_path_factory):
    """A real MP4 of featureless grey frames: no lines, no layout."""
    import cv2

    path = tmp_path_factory.mktemp("blank") / "blank.mp4"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (320, 240))
    for _ in range(4):
        w.write(np.full((240, 320, 3), 128, np.uint8))
    w.release()
    return path


@pytest.fixture
def client():
    """A bare ground station on 127.0.0.1 (:class:`helpers.ground_station.Client`), closed
    after the test."""
    c = Client()
    yield c
    c.close()
