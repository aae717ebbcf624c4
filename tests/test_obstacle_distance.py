"""OBSTACLE_DISTANCE for PX4's Collision Prevention: the sectors (pure) and the stream that
reaches the mock autopilot through the real MAVSDK."""

import math
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
from helpers.processes import free_udp_port
from test_offboard_sitl import Running

from companion.config import Config
from companion.control.obstacle_distance import UNKNOWN, from_estimate, obstacle_distance
from companion.control.policy import TurnCommand
from companion.vision.pipeline import Pipeline
from companion.vision.ranging import FloorContact
from sitl.closed_loop import hovering_autopilot, sitl_link
from sitl.sample import sample_scene
from sitl.scene import render


def _contact(range_m, bearing_deg):
    return FloorContact(range_m, bearing_deg, (0.0, 0.0))


def test_sectors_hold_the_face_between_two_feet_and_nothing_else():
    # A face from 3 m at −9° to 3 m at +9°: its nearest point is 2.96 m straight ahead.
    od = obstacle_distance([[_contact(3.0, -9.0), _contact(3.0, 9.0)]], hfov_deg=90.0,
                           vfov_deg=73.7, camera_height_m=1.2, focal_px=320.0)
    assert od.increment_deg == 5.0 and len(od.distances_cm) == 72
    n = 18  # 90° of 5° sectors
    assert od.angle_offset_deg == pytest.approx(-42.5)
    known = {round(od.sector_bearing_deg(i)): d for i, d in enumerate(od.distances_cm[:n])
             if d != UNKNOWN}
    assert set(known) == {-8, -2, 2, 8}  # sectors centred −7.5 … +7.5°, rounded
    assert min(known.values()) == pytest.approx(300 * math.cos(math.radians(9)) /
                                                math.cos(math.radians(2.5)), abs=1)
    assert all(d == UNKNOWN for d in od.distances_cm[n:])
    assert od.min_distance_cm == round(100 * 1.2 / math.tan(math.radians(73.7 / 2)))
    assert od.max_distance_cm == 2000  # 0.1 · h · f = 38 m, capped at 20 m


def test_a_contact_beyond_reach_is_unknown_never_free():
    od = obstacle_distance([[_contact(60.0, 0.0)]], 90.0, 73.7, 1.2, 320.0)
    assert set(od.distances_cm) == {UNKNOWN}  # max + 1 would declare the sector free


def _truth_distance(box, cam, bearing_deg):
    """Along the horizontal ray at ``bearing_deg`` right of the camera's heading, the
    distance to the box's footprint (None if it misses)."""
    a = math.radians(cam.yaw_deg + bearing_deg)
    o, u = np.array([cam.x, cam.y]), np.array([math.cos(a), math.sin(a)])
    fp = box.footprint()[:, :2]
    best = None
    for p, q in zip(fp, np.roll(fp, -1, axis=0), strict=True):
        d = q - p
        den = u[0] * d[1] - u[1] * d[0]
        if abs(den) < 1e-12:
            continue
        w = p - o
        t = (w[0] * d[1] - w[1] * d[0]) / den
        s = (w[0] * u[1] - w[1] * u[0]) / den
        if t > 0 and 0 <= s <= 1:
            best = t if best is None else min(best, t)
    return best


def test_the_stream_reaches_the_autopilot_at_10_hz_and_is_never_too_far():
    port = free_udp_port()
    scene, cam = sample_scene()
    cam = replace(cam, height_m=1.3)
    image, _ = render(scene, cam)
    cfg = sitl_link(Config(), port)
    cfg = replace(cfg, offboard=replace(cfg.offboard, enabled=False))  # streamed regardless
    with hovering_autopilot(port, takeoff_alt_m=1.3).start() as ap, Running(cfg) as run:
        ctl = run.controller
        assert ap.wait_for(lambda: ctl.camera_height_m() is not None, 8.0)
        height = ctl.camera_height_m()
        est = Pipeline()(image, camera_height_m=height)
        sectors = from_estimate(est)
        assert sectors is not None
        stop = threading.Event()

        def camera():  # the vision thread at 15 Hz
            while not stop.is_set():
                ctl.submit(TurnCommand("forward", 0.0, 0.0), est.eta_deg,
                           obstacle_distance=sectors)
                stop.wait(1 / 15)

        feeder = threading.Thread(target=camera, daemon=True)
        feeder.start()
        time.sleep(0.5)
        t0 = time.monotonic()
        time.sleep(2.0)
        got = [m for t, m in ap.obstacle_distances if t >= t0]
        stop.set()
        feeder.join(1)
        # Vision stalls: the stream goes on, claiming nothing, once stale_after_s has passed.
        stalled = time.monotonic() + cfg.offboard.stale_after_s + 0.2
        time.sleep(cfg.offboard.stale_after_s + 0.8)
        late = [m for t, m in ap.obstacle_distances if t >= stalled]
    assert len(late) >= 3 and all(set(m["distances"]) == {UNKNOWN} for m in late)
    assert height == pytest.approx(1.3, abs=0.05)
    assert len(got) >= 2.0 * 10 * 0.9  # mavlink.obstacle_distance_hz = 10
    msg = got[-1]
    assert msg["frame"] == 12 and msg["increment_f"] == pytest.approx(5.0)
    assert msg["min_distance"] > 0 and msg["max_distance"] > msg["min_distance"]
    box = scene.boxes[0]
    checked = 0
    for i, d in enumerate(msg["distances"]):
        if d == UNKNOWN:
            continue
        truth = _truth_distance(box, cam, msg["angle_offset"] + i * msg["increment_f"])
        if truth is not None and 1.0 <= truth <= 6.0:
            checked += 1
            assert d / 100 <= 1.2 * truth, (i, d, truth)  # never > 20 % too far
    assert checked >= 1
