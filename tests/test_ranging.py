"""Range from the floor plane (companion/vision/ranging.py) and in the pipeline."""

import math
from dataclasses import replace

import numpy as np
import pytest
from helpers.camera import tilted_camera

from companion.vision.pipeline import Pipeline
from companion.vision.ranging import (
    FloorContact,
    down_direction,
    floor_contacts,
    floor_point,
    floor_points,
    foot_line,
    hidden_extent,
    obstacle_contact,
    path_distance,
)
from sitl.sample import sample_scene
from sitl.scene import render

CENTRE = np.array([319.5, 239.5])
F = 320.0
STRAIGHT_DOWN = np.array([0.0, 1.0, 0.0])  # V3 of a level camera: at infinity, downward


def test_a_level_camera_sees_the_floor_at_h_f_over_the_row_offset():
    down = down_direction(STRAIGHT_DOWN, F, CENTRE)
    c = floor_point((319.5, 239.5 + 80.0), down, F, CENTRE, 1.2)
    assert c.range_m == pytest.approx(1.2 * F / 80.0)
    assert c.bearing_deg == pytest.approx(0.0, abs=1e-9)
    right = floor_point((319.5 + 80.0, 239.5 + 80.0), down, F, CENTRE, 1.2)
    assert right.bearing_deg == pytest.approx(math.degrees(math.atan(80.0 / F)))
    assert floor_point((319.5, 200.0), down, F, CENTRE, 1.2) is None  # above the horizon


def test_a_pitched_camera_uses_v3_not_the_image_rows():
    # Pitched 10° down: the horizon is above the centre and V3 is finite below.
    pitch = math.radians(10.0)
    v3 = np.array([CENTRE[0], CENTRE[1] + F / math.tan(pitch), 1.0])
    down = down_direction(v3, F, CENTRE)
    c = floor_point(CENTRE, down, F, CENTRE, 1.0)  # the optical axis
    assert c.range_m == pytest.approx(1.0 / math.tan(pitch))


def _tilted_camera(pitch_deg, roll_deg):
    """The tilted camera's rotation (:func:`helpers.camera.tilted_camera`) and its V3."""
    rot = tilted_camera(pitch_deg, roll_deg)
    d = rot @ np.array([0.0, 1.0, 0.0])
    return rot, np.array([F * d[0] + CENTRE[0] * d[2], F * d[1] + CENTRE[1] * d[2], d[2]])


def _pixel(rot, point):
    pc = rot @ point
    return CENTRE + F * pc[:2] / pc[2]


@pytest.mark.parametrize("pitch, roll", [(0.0, 0.0), (6.0, 0.0), (-4.0, 5.0), (3.0, -8.0)])
def test_floor_points_of_a_tilted_camera_give_range_and_bearing_on_the_floor(pitch, roll):
    rot, v3 = _tilted_camera(pitch, roll)
    h = 1.1
    ahead_right = [(2.0, 0.0), (3.0, -1.0), (1.5, 0.7), (6.0, 2.5)]
    pixels = np.array([_pixel(rot, np.array([y, h, x])) for x, y in ahead_right]
                      + [_pixel(rot, np.array([0.0, -0.5, 4.0]))])  # above the horizon
    got = floor_points(pixels, down_direction(v3, F, CENTRE), F, CENTRE, h)
    assert got[-1] is None
    for (x, y), c in zip(ahead_right, got[:-1], strict=True):
        assert c.range_m == pytest.approx(math.hypot(x, y), rel=1e-9)
        assert c.bearing_deg == pytest.approx(math.degrees(math.atan2(y, x)), abs=1e-9)
        assert c.ahead_right_m == pytest.approx((x, y), abs=1e-9)


def test_floor_contacts_are_the_feet_of_every_vertical_edge_sorted_by_bearing():
    rot, v3 = _tilted_camera(4.0, -3.0)
    h = 1.0
    # A box face on the floor 2.5–3.5 m ahead, 0.8 m tall, its two vertical edges and a
    # top corner with no bottom partner in view.
    feet = [(3.5, 0.6), (2.5, -0.4)]
    corners = []
    for x, y in feet:
        corners += [_pixel(rot, np.array([y, h, x])), _pixel(rot, np.array([y, h - 0.8, x]))]
    corners.append(_pixel(rot, np.array([1.5, h - 0.8, 4.0])))
    got = floor_contacts(np.array(corners), v3, F, CENTRE, h)
    assert [c.ahead_right_m for c in got] == [pytest.approx(f, abs=1e-9) for f in
                                              sorted(feet, key=lambda f: math.atan2(f[1], f[0]))]


def test_a_corner_with_no_partner_below_or_above_gives_no_range():
    assert obstacle_contact(np.array([[300.0, 300.0]]), STRAIGHT_DOWN, F, CENTRE, 1.2) is None
    # Two corners side by side are not a vertical edge either.
    pts = np.array([[300.0, 300.0], [360.0, 300.0]])
    assert obstacle_contact(pts, STRAIGHT_DOWN, F, CENTRE, 1.2) is None


def test_the_lower_corner_of_a_vertical_edge_is_the_floor_contact():
    pts = np.array([[300.0, 200.0], [300.0, 319.5]])  # top, bottom of one edge
    c = obstacle_contact(pts, STRAIGHT_DOWN, F, CENTRE, 1.2)
    assert c.pixel == (300.0, 319.5)
    assert c.top_pixel == (300.0, 200.0)  # the edge it is the foot of
    assert c.range_m == pytest.approx(1.2 * F / 80.0 * math.hypot(1, 19.5 / F), rel=1e-6)


@pytest.mark.parametrize("pitch, roll", [(0.0, 0.0), (4.0, 0.0), (-3.0, 3.0)])
def _inside(point, polygon, tol_m):
    """Whether ``point`` lies in the convex ``polygon`` [(x, y), ...] or within ``tol_m``
    of it."""
    pts = np.asarray(polygon, float)
    p = np.asarray(point, float)
    inside, best = True, math.inf
    for a, b in zip(pts, np.roll(pts, -1, axis=0), strict=True):
        ab, ap = b - a, p - a
        t = float(np.clip(ap @ ab / (ab @ ab), 0.0, 1.0))
        best = min(best, float(np.linalg.norm(ap - t * ab)))
        inside &= (ab[0] * ap[1] - ab[1] * ap[0]) * _orientation(pts) >= 0.0
    return inside or best <= tol_m


def _orientation(pts):
    return math.copysign(1.0, sum(a[0] * b[1] - a[1] * b[0]
                                  for a, b in zip(pts, np.roll(pts, -1, axis=0), strict=True)))


def _seen_box(seen, pitch=3.0, roll=-2.0, h=1.0, top_m=0.7):
    """A box 1.2 × 0.8 m turned 30° off the line of sight, its near corner 2.5 m ahead:
    its floor corners (ahead, right; near, left, back, right), the pixels of the corners
    ``seen`` (indices into those) and of their tops, its two OVPs and V3."""
    rot, v3 = _tilted_camera(pitch, roll)
    a = math.radians(30.0)
    u1 = np.array([math.cos(a), math.sin(a)])  # the near corner to the right one
    u2 = np.array([math.sin(a), -math.cos(a)])  # ... to the left one
    near = np.array([2.5, 0.1])
    floor = [near, near + 0.8 * u2, near + 0.8 * u2 + 1.2 * u1, near + 1.2 * u1]
    pixels = []
    for k in seen:
        x, y = floor[k]
        pixels += [_pixel(rot, np.array([y, h, x])), _pixel(rot, np.array([y, h - top_m, x]))]
    ovps = []
    for u in (u1, u2):
        d = rot @ np.array([u[1], 0.0, u[0]])
        ovps.append([F * d[0] + CENTRE[0] * d[2], F * d[1] + CENTRE[1] * d[2], d[2]])
    return [tuple(f) for f in floor], np.array(pixels), np.array(ovps), v3


def test_the_foot_of_a_face_between_two_feet_is_sampled_between_them():
    # Feet 1.1 m apart across the path, 3 m ahead: neither is in it, the face between is.
    left, right = at(3.0, -0.6), at(3.0, 0.5)
    got = foot_line([left, right], step_m=0.25)
    assert len(got) == 4  # 1.1 m in 5 steps of 0.22 m: the 4 points between
    assert all(p[0] == pytest.approx(3.0) for p in got)
    gaps = np.diff([-0.6] + [p[1] for p in got] + [0.5])
    assert gaps == pytest.approx([0.22] * 5)
    assert path_distance([[left, right]], 0.3) == pytest.approx(3.0)  # as path_distance
    assert foot_line([left]) == [] and foot_line([]) == []


def test_the_floor_behind_a_box_s_feet_is_taken_along_the_faces_leading_away():
    floor, pixels, ovps, v3 = _seen_box(seen=(0, 1, 3))  # the near corner and both sides
    h = 1.0
    feet = floor_contacts(pixels, v3, F, CENTRE, h)
    got = hidden_extent(pixels, feet, ovps, v3, F, CENTRE, h, depth_m=0.5)
    assert hidden_extent(pixels, feet, ovps, v3, F, CENTRE, h, depth_m=0.0) == []
    assert hidden_extent(pixels, (), ovps, v3, F, CENTRE, h, depth_m=0.5) == []
    # Every point is on the box's floor: the faces seen run from the near foot to the
    # side feet and no farther; behind each side foot, the hidden side 0.5 m deep.
    assert got and all(_inside(p, floor, 1e-6) for p in got)
    near, left, back, right = (np.array(f) for f in floor)
    for start, toward in ((left, back), (right, back), (near, left), (near, right)):
        reach = min(0.5, float(np.linalg.norm(toward - start))) if start is not near else \
            float(np.linalg.norm(toward - start))
        end = start + (toward - start) / np.linalg.norm(toward - start) * reach
        assert min(np.linalg.norm(np.array(p) - end) for p in got) < 0.1


def test_a_face_seen_alone_is_not_taken_past_its_far_foot():
    # One face seen (the near corner and the left one, no corner of the right face): its
    # far foot ends it; behind both feet lies the side not seen.
    floor, pixels, ovps, v3 = _seen_box(seen=(0, 1), pitch=0.0, roll=0.0)
    got = hidden_extent(pixels, floor_contacts(pixels, v3, F, CENTRE, 1.0), ovps, v3, F,
                        CENTRE, 1.0, depth_m=0.75)
    assert got and all(_inside(p, floor, 1e-6) for p in got)
    near, left = np.array(floor[0]), np.array(floor[1])
    assert max(np.linalg.norm(np.array(p) - near) for p in got) > 0.7  # 0.75 m behind
    assert max(np.linalg.norm(np.array(p) - left) for p in got) > 0.7
    # Without the rule that the far foot ends its face, the face would be taken on
    # beyond it (the direction leading away from the camera there): outside the box.
    assert max(float((np.array(p) - near) @ (left - near)) / 0.8 for p in got) <= 0.8 + 1e-6


def test_a_face_seen_back_to_a_corner_whose_foot_is_hidden_is_taken_to_that_corner():
    # The left foot measured; of the near corner only the top is seen (its foot hidden
    # or below the view), so no second foot bounds the face between them. That face is
    # seen, and it lies across the way back to the course: its floor is covered.
    floor, pixels, ovps, v3 = _seen_box(seen=(1, 0), pitch=0.0, roll=0.0)
    pixels = pixels[[0, 1, 3]]  # the left edge, the near edge's top
    feet = floor_contacts(pixels, v3, F, CENTRE, 1.0)
    assert len(feet) == 1
    got = hidden_extent(pixels, feet, ovps, v3, F, CENTRE, 1.0, depth_m=0.5)
    assert got and all(_inside(p, floor, 1e-6) for p in got)
    near, left = np.array(floor[0]), np.array(floor[1])
    assert min(np.linalg.norm(np.array(p) - near) for p in got) < 1e-6  # to the corner
    u = (left - near) / np.linalg.norm(left - near)
    on_face = [p for p in got if abs(u[0] * (p[1] - near[1]) - u[1] * (p[0] - near[0])) < 1e-6]
    assert len(on_face) >= 3  # 0.8 m at most 0.25 m apart


@pytest.mark.parametrize("pitch, roll", [(0.0, 0.0), (4.0, 0.0), (-3.0, 3.0)])
def test_the_pipeline_measures_the_range_of_a_rendered_box(pitch, roll):
    scene, cam = sample_scene()
    cam = replace(cam, pitch_deg=pitch, roll_deg=roll)
    image, truth = render(scene, cam)
    est = Pipeline()(image, camera_height_m=cam.height_m)
    assert est.range_m is not None
    nearest = min(truth.obstacles[0].floor_corners,
                  key=lambda c: math.hypot(c[0] - est.contact.pixel[0],
                                           c[1] - est.contact.pixel[1]))
    assert truth.obstacles[0].floor_corners
    assert est.range_m == pytest.approx(nearest[2], rel=0.05)
    # What the supervisor remembers: every contact, ahead and right of the camera, the
    # nearest the range, on the side of the image it was seen on.
    flat = [c for contacts in est.obstacle_contacts for c in contacts]
    assert len(est.contacts_ahead_right_m) == len(flat) >= 1
    assert min(math.hypot(*c) for c in est.contacts_ahead_right_m) == pytest.approx(est.range_m)
    for (ahead, right), c in zip(est.contacts_ahead_right_m, flat, strict=True):
        assert ahead > 0.0  # pitch turns the image about its x axis: the side is the same
        assert roll != 0.0 or (right > 0.0) == (c.pixel[0] > image.shape[1] / 2)
    # ... the floor between them and behind them, on the box's footprint to the range's
    # accuracy.
    feet = est.footprint_ahead_right_m(0.0)
    assert feet[:len(flat)] == est.contacts_ahead_right_m
    assert len(feet) > len(flat) or len(flat) == 1  # the foot of a face between two feet
    more = est.footprint_ahead_right_m(0.5)
    assert more[:len(feet)] == feet and len(more) > len(feet)
    yaw = math.radians(cam.yaw_deg)
    box = [((x - cam.x) * math.cos(yaw) + (y - cam.y) * math.sin(yaw),
            -(x - cam.x) * math.sin(yaw) + (y - cam.y) * math.cos(yaw))
           for x, y, *_ in scene.boxes[0].footprint()]
    assert all(_inside(p, box, 0.05 * math.hypot(*p)) for p in more)


def test_no_height_no_range():
    scene, cam = sample_scene()
    image, _ = render(scene, cam)
    est = Pipeline()(image)
    assert est.eta_deg is not None and est.range_m is None and est.path_m(0.5) is None


def at(x_m, y_m):
    """A floor contact x ahead, y right of the camera."""
    return FloorContact(math.hypot(x_m, y_m), math.degrees(math.atan2(y_m, x_m)), (0.0, 0.0))


def test_path_distance_is_the_nearest_foot_or_face_inside_the_corridor():
    # A face slanting across the path, its feet outside the corridor on both sides.
    face = [at(2.0, -1.0), at(3.0, 1.0)]
    assert path_distance([face], 0.5) == pytest.approx(2.25)  # where it crosses y = -0.5
    assert path_distance([[at(1.5, 0.2)], face], 0.5) == pytest.approx(1.5)
    # Feet and face beside the path: nothing in it.
    assert math.isinf(path_distance([[at(1.0, 0.8), at(2.0, 1.5)]], 0.5))
    assert math.isinf(path_distance([], 0.5))


def test_the_pipeline_reports_the_path_distance_of_a_box_ahead():
    scene, cam = sample_scene()
    image, truth = render(scene, cam)
    est = Pipeline()(image, camera_height_m=cam.height_m)
    # A corridor wide enough for every foot: the nearest one's distance along the
    # optical axis, no more than its range and no less than its range · cos(hfov / 2).
    ahead = est.path_m(10.0)
    assert est.range_m * math.cos(math.radians(cam.hfov_deg / 2)) <= ahead <= est.range_m
    assert est.path_m(0.5) >= ahead
