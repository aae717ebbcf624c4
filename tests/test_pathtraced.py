"""The second renderer (sitl/pathtraced.py, Mitsuba 3) and the pipeline on its pictures."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from companion.config import Config
from companion.vision.pipeline import Pipeline
from sitl.pathtraced import (
    Furniture,
    Look,
    Room3D,
    _undistort_map,
    distort_points,
    random_room,
    render,
)
from sitl.sample import sample_scene
from sitl.scene import Rug


def _room(kind="box", **look):
    scene, cam = sample_scene()
    piece = Furniture(kind, 4.4, 0.3, 30.0, 1.2, 0.7, 1.0, (0.3, 0.35, 0.55), "paint")
    return Room3D(scene.room, (piece,), Look(spp=8, seed=3, **look)), replace(
        cam, width=320, height=240)


def test_a_rotated_box_is_found_in_a_path_traced_room():
    r3, cam = _room(window_power=0.0, distortion_k1=0.0)
    image, truth = render(r3, cam)
    assert image.shape == (240, 320, 3) and image.dtype == np.uint8
    assert image.std() > 10  # a picture, not a flat field
    target = truth.obstacles[0]
    assert target.non_manhattan and target.detectable
    cfg = Config()
    est = Pipeline(replace(cfg, camera=replace(cfg.camera, focal_px=cam.focal_px)))(image)
    assert est.eta_deg == pytest.approx(target.eta_deg, abs=1.5)


@pytest.mark.parametrize("kind", ["table", "cabinet", "sofa"])
def test_furniture_that_is_not_a_box_renders_and_has_truth(kind):
    r3, cam = _room(kind)
    image, truth = render(r3, cam)
    assert truth.obstacles[0].non_manhattan and truth.obstacles[0].kind == kind
    assert truth.obstacles[0].eta_deg == pytest.approx(35.0, abs=0.01)  # 30° − (−5°), level
    # The furniture darkens the floor and wall where it stands: its parts were drawn.
    empty, _ = render(replace(r3, furniture=()), cam)
    assert np.abs(image.astype(int) - empty.astype(int)).mean() > 2.0


def test_a_room_renders_to_the_same_picture_every_time():
    # The frozen splits are frozen in pixels only if the path tracer is deterministic.
    r3, cam = _room()
    first, _ = render(r3, cam)
    again, _ = render(r3, cam)
    assert np.array_equal(first, again)


def test_a_videos_frames_draw_new_noise_on_the_same_textures():
    # Frame k of a video (Look.frame) must not redraw the wood grain or the wallpaper: a
    # floor that changes from frame to frame is no room a camera flies through.
    r3, cam = _room(floor="planks", wall="stripes", shot_noise=0.0, read_noise=0.0)
    r3 = replace(r3, look=replace(r3.look, spp=32))

    def frame(look):
        return render(replace(r3, look=look), cam)[0].astype(float)

    one, two = frame(replace(r3.look, frame=1)), frame(replace(r3.look, frame=2))
    other_room = frame(replace(r3.look, seed=r3.look.seed + 1, frame=1))
    assert not np.array_equal(one, two)  # the path tracer's grain is drawn afresh
    noise = np.abs(cv2.GaussianBlur(one - two, (0, 0), 3)).mean()  # 0.8 grey levels
    textures = np.abs(cv2.GaussianBlur(one - other_room, (0, 0), 3)).mean()  # 2.2
    assert noise < 0.5 * textures, (noise, textures)


def test_a_rug_lies_on_the_floor_with_its_stripes():
    r3, cam = _room(window_power=0.0, distortion_k1=0.0)
    room = replace(r3.room, rug=Rug(3.0, -0.6, 25.0, 1.6, 1.0, (0.2, 0.5, 0.3)))
    plain, _ = render(r3, cam)
    rugged, truth = render(replace(r3, room=room), cam)
    # The rug changes the light everywhere a little (one bounce), and the grain with it.
    changed = cv2.GaussianBlur(np.abs(rugged.astype(float) - plain).max(axis=2), (0, 0),
                               1.5) > 20
    rows = np.nonzero(changed.any(axis=1))[0]
    assert changed.sum() > 200
    assert rows.min() > cam.height / 2  # below the horizon: on the floor, nothing stands up
    assert truth.obstacles == render(r3, cam)[1].obstacles  # the truth does not see it


def test_lens_distortion_moves_corners_with_the_pixels():
    _, cam = _room()
    k1 = 0.04
    mx, my = _undistort_map(cam, k1)
    # distort_points inverts the map: the output pixel that reads a point reads it back.
    for v, u in ((10, 15), (200, 300), (120, 160), (5, 310)):
        d = distort_points(cam, k1, np.array([[mx[v, u], my[v, u]]]))[0]
        assert d == pytest.approx([u, v], abs=1e-3)


def test_random_rooms_are_reproducible_and_varied():
    a = random_room(np.random.default_rng([5, 1]), 320, 240)
    b = random_room(np.random.default_rng([5, 1]), 320, 240)
    assert a == b
    kinds = {f.kind for i in range(12)
             for f in random_room(np.random.default_rng([5, i]), 320, 240)[0].furniture}
    assert {"table", "cabinet", "sofa", "box"} <= kinds


def test_a_pathtraced_clip_is_rendered_once_then_read_back(tmp_path, monkeypatch):
    from sitl.evaluate import evaluate_clip

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    first = evaluate_clip(21, 0, frames=2, renderer="pathtraced")
    frames = sorted(tmp_path.rglob("*.png"))
    assert len(first) == 2 and len(frames) == 2
    a, b = (cv2.imread(str(p)) for p in frames)
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 1.0  # the camera yawed
    assert all(p.parent.name == "clips-2" for p in frames)  # not the older renders' folder
    assert evaluate_clip(21, 0, frames=2, renderer="pathtraced") == first  # from the cache


def _render_with_a_peer(barrier, room, cam, name, results):
    """Child process: render through the cache, waiting for the peer before writing."""
    import sitl.pathtraced as pathtraced
    from sitl.evaluate import _render_cached

    real = pathtraced.render

    def render_then_wait(r3, c):
        out = real(r3, c)
        barrier.wait(timeout=60)  # both write the frame at the same moment
        return out

    pathtraced.render = render_then_wait
    try:
        image, _ = _render_cached(name, room, cam)
        results.put(image.shape)
    except Exception as e:  # reported to the test, which fails on it
        results.put(repr(e))


def test_two_workers_rendering_one_frame_both_cache_it(tmp_path, monkeypatch):
    # With --mirrored a scene and its mirror are two jobs that draw the same frame: two
    # workers render it at once into one cache file, and neither may fail.
    import multiprocessing

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    room, cam = _room()
    room = replace(room, look=replace(room.look, spp=1))
    ctx = multiprocessing.get_context("fork")
    barrier, results = ctx.Barrier(2), ctx.Queue()
    procs = [ctx.Process(target=_render_with_a_peer, args=(barrier, room, cam, "f.png", results))
             for _ in range(2)]
    for p in procs:
        p.start()
    got = [results.get(timeout=120) for _ in procs]
    for p in procs:
        p.join()
    assert got == [(240, 320, 3)] * 2
    assert [p.name for p in tmp_path.rglob("*.png")] == ["f.png"]
