"""How far an obstacle is: range from the floor plane (not in the paper).

η says which way an obstacle's face points, not how far away it is. The floor is a plane
the layout already fixes: its normal is the vertical direction, ``d = K⁻¹ V3`` (so pitch
and roll are taken into account), and the camera stands ``h`` metres above it. A pixel
``p`` whose ray ``r = K⁻¹ [p, 1]`` goes below the horizon meets the floor at
``X = h · r / (r · d)``; the horizontal distance and bearing of ``X`` are the range and
bearing of whatever stands on the floor there.

An obstacle's floor contact is the lower corner of one of its vertical edges: of two of
its corners on one line through V3, the one farther down. A top corner alone is never
used, since its ray meets the floor beyond the obstacle (a range too far, the dangerous
direction). Pure functions over arrays; distances in metres, angles in degrees.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["FloorContact", "floor_point", "floor_points", "floor_contacts", "obstacle_contact",
           "down_direction", "path_distance", "foot_line", "hidden_extent"]

VERTICAL_EDGE_TOL_DEG = 2.0
"""two corners are on one vertical edge when their line points at V3 within this"""

MIN_DEPRESSION_DEG = 1.0
"""a ray less than this below the horizon meets the floor too far away to trust"""

FACE_TOL_DEG = 3.0
"""a corner lies on a face through a foot when its line to the face's OVP passes through
the foot, or the top of the foot's vertical edge, within this"""


@dataclass(frozen=True)
class FloorContact:
    """Where something meets the floor: ``range_m`` horizontal distance from the camera,
    ``bearing_deg`` right of the camera's forward direction (projected on the floor),
    ``pixel`` the image point (x, y); ``top_pixel`` the upper corner of the vertical edge
    whose foot it is (:func:`floor_contacts`), None for a floor point alone."""

    range_m: float
    bearing_deg: float
    pixel: tuple[float, float]
    top_pixel: tuple[float, float] | None = None

    @property
    def ahead_right_m(self) -> tuple[float, float]:
        """The contact on the floor: metres ahead of the camera and to its right."""
        b = math.radians(self.bearing_deg)
        return self.range_m * math.cos(b), self.range_m * math.sin(b)


def down_direction(v3: np.ndarray, focal_px: float, centre: np.ndarray) -> np.ndarray:
    """Unit vector of the world's down direction in camera coordinates (x right, y down,
    z forward), from the vertical VP ``v3`` (homogeneous pixels); zero for a degenerate
    ``v3``. Scalar arithmetic (:func:`~companion.vision.geometry.direction_of` of one
    point): it runs for every obstacle of every frame in flight."""
    x, y, w = (float(t) for t in np.asarray(v3, dtype=float).reshape(3))
    dx, dy, dz = x - float(centre[0]) * w, y - float(centre[1]) * w, focal_px * w
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    if n == 0.0:
        return np.zeros(3)
    if dy < 0:  # the camera is upright: down is down in the image
        n = -n
    return np.array([dx / n, dy / n, dz / n])


def _floor_axes(down) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The camera's forward and right directions levelled onto the floor (unit, camera
    coordinates): forward without its down part; right = down × forward."""
    dx, dy, dz = (float(t) for t in down)
    fx, fy, fz = -dz * dx, -dz * dy, 1.0 - dz * dz
    fn = math.sqrt(fx * fx + fy * fy + fz * fz)
    fx, fy, fz = fx / fn, fy / fn, fz / fn
    return (fx, fy, fz), (dy * fz - dz * fy, dz * fx - dx * fz, dx * fy - dy * fx)


def floor_point(pixel, down: np.ndarray, focal_px: float, centre: np.ndarray,
                camera_height_m: float) -> FloorContact | None:
    """The floor point seen at ``pixel`` (x, y), None above or too near the horizon.

    Inputs: ``down`` from :func:`down_direction`; ``focal_px``, ``centre`` the camera;
    ``camera_height_m`` above the floor.
    """
    return floor_points(np.asarray(pixel, dtype=float).reshape(1, 2), down, focal_px, centre,
                        camera_height_m)[0]


def floor_points(pixels: np.ndarray, down: np.ndarray, focal_px: float, centre: np.ndarray,
                 camera_height_m: float) -> list[FloorContact | None]:
    """:func:`floor_point` of each row of ``pixels`` (K×2). Scalar arithmetic: K is a
    handful of corners, for which numpy's per-call cost is most of the time."""
    dx, dy, dz = (float(t) for t in down)
    cx, cy = float(centre[0]), float(centre[1])
    (fx, fy, fz), (rx, ry, rz) = _floor_axes(down)
    min_s = math.sin(math.radians(MIN_DEPRESSION_DEG))
    out: list[FloorContact | None] = []
    for x, y in np.asarray(pixels, dtype=float).reshape(-1, 2).tolist():
        ux, uy = (x - cx) / focal_px, (y - cy) / focal_px
        un = math.sqrt(ux * ux + uy * uy + 1.0)
        s = (ux * dx + uy * dy + dz) / un  # sine of the ray's depression below the horizon
        if s < min_s:
            out.append(None)
            continue
        k = camera_height_m / (s * un)  # the ray (ux, uy, 1) scaled to meet the floor
        px, py, pz = k * ux, k * uy, k
        along = px * dx + py * dy + pz * dz
        hx, hy, hz = px - along * dx, py - along * dy, pz - along * dz
        bearing = math.degrees(math.atan2(hx * rx + hy * ry + hz * rz,
                                          hx * fx + hy * fy + hz * fz))
        out.append(FloorContact(math.sqrt(hx * hx + hy * hy + hz * hz), bearing, (x, y)))
    return out


def _passes_through(c, p, vp, sin_tol: float) -> bool:
    """Whether the line from corner ``c`` (x, y) toward the homogeneous point ``vp`` (which
    may be at infinity) passes through ``p`` (x, y), at least a pixel away, within the
    angle whose sine is ``sin_tol``."""
    ax, ay = p[0] - c[0], p[1] - c[1]
    bx, by = vp[0] - vp[2] * c[0], vp[1] - vp[2] * c[1]
    na, nb = math.hypot(ax, ay), math.hypot(bx, by)
    return na >= 1.0 and nb >= 1e-12 and abs(ax * by - ay * bx) <= sin_tol * na * nb


def _feet(pts: list, v3: np.ndarray, down: np.ndarray, focal_px: float,
          centre: np.ndarray) -> list[tuple[int, int]]:
    """Each foot among the corners ``pts`` [(x, y), ...] with the top of its edge: (i, j)
    where ``pts[i]`` lies farther down than ``pts[j]`` on one line through V3."""
    dx, dy, dz = (float(t) for t in down)
    v3h = [float(t) for t in np.asarray(v3, dtype=float).reshape(3)]
    cx, cy = float(centre[0]), float(centre[1])
    tol = math.sin(math.radians(VERTICAL_EDGE_TOL_DEG))
    # depression: the sine of the angle a corner's ray (u, 1) makes below the horizon.
    depression = []
    for x, y in pts:
        ux, uy = (x - cx) / focal_px, (y - cy) / focal_px
        depression.append((ux * dx + uy * dy + dz) / math.sqrt(1.0 + ux * ux + uy * uy))
    feet = []
    for i, p in enumerate(pts):
        # i lies farther down than a corner j on its vertical line: the foot of their edge.
        for j, c in enumerate(pts):
            if depression[i] > depression[j] and _passes_through(c, p, v3h, tol):
                feet.append((i, j))
                break
    return feet


def floor_contacts(corners_px: np.ndarray, v3: np.ndarray, focal_px: float,
                   centre: np.ndarray, camera_height_m: float) -> list[FloorContact]:
    """Every floor contact of an obstacle whose corner projections are ``corners_px``
    (K×2): the lower corner of each pair of its corners on one line through V3, seen on
    the floor, sorted by bearing, each with the upper corner of its edge (``top_pixel``).
    Empty when no two corners share a vertical edge.

    Scalar arithmetic over the K² pairs: K is a handful of corners, and the service
    ranges every obstacle of every frame."""
    pts = np.asarray(corners_px, dtype=float).reshape(-1, 2).tolist()
    if len(pts) < 2:
        return []
    down = down_direction(v3, focal_px, centre)
    feet = _feet(pts, v3, down, focal_px, centre)
    out = floor_points(np.array([pts[i] for i, _ in feet]).reshape(-1, 2), down, focal_px,
                       centre, camera_height_m)
    return sorted((FloorContact(c.range_m, c.bearing_deg, c.pixel, tuple(pts[j]))
                   for c, (_, j) in zip(out, feet, strict=True) if c is not None),
                  key=lambda c: c.bearing_deg)


def _between(a: tuple[float, float], b: tuple[float, float], step_m: float
             ) -> list[tuple[float, float]]:
    """Points from ``a`` (excluded) to ``b`` (included) on the floor, evenly spaced at most
    ``step_m`` apart; each (m ahead, m right)."""
    steps = max(1, math.ceil(math.hypot(b[0] - a[0], b[1] - a[1]) / step_m - 1e-9))
    return [(a[0] + (b[0] - a[0]) * k / steps, a[1] + (b[1] - a[1]) * k / steps)
            for k in range(1, steps + 1)]


def foot_line(contacts: Sequence[FloorContact], step_m: float = 0.25
              ) -> list[tuple[float, float]]:
    """Floor points between neighbouring contacts of one obstacle (``contacts`` sorted by
    bearing, :func:`floor_contacts`), at most ``step_m`` apart, each (m ahead of the
    camera, m to its right): the foot of the face seen between two feet, as
    :func:`path_distance` takes it. A face across the path between two feet beside it
    stands in the path although neither foot does."""
    pts = [c.ahead_right_m for c in contacts]
    return [p for a, b in zip(pts, pts[1:], strict=False) for p in _between(a, b, step_m)[:-1]]


def _cross(a, b) -> tuple[float, float, float]:
    """a × b of two 3-sequences: the line through two homogeneous points, or the point
    where two lines meet."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def hidden_extent(corners_px: np.ndarray, contacts: Sequence[FloorContact], ovps: np.ndarray,
                  v3: np.ndarray, focal_px: float, centre: np.ndarray, camera_height_m: float,
                  depth_m: float, step_m: float = 0.25) -> list[tuple[float, float]]:
    """Floor points an obstacle is taken to cover beyond its measured feet, each (m ahead
    of the camera, m to its right): what one view cannot measure, and the foot of a face
    seen up to a corner whose own foot is not measured.

    An obstacle's faces run from each foot along its two horizontal axes (the OVPs
    ``ovps[0]``, ``ovps[1]``, homogeneous pixels); a face turned away from the camera is
    hidden, and so is how far the obstacle reaches behind what is seen. From each foot
    (``contacts``: the obstacle's :func:`floor_contacts`, which name the top of each foot's
    edge), along each axis in the direction that leads away from the camera, the floor is
    sampled at most ``step_m`` apart for ``depth_m``, or as far as the last corner seen on
    that face (the foot of its vertical line, through V3) if that is farther. Along an axis
    on which a corner of the obstacle is seen on the near side of the foot, that face is
    seen to end at the foot and to run back from it: the floor is sampled from the foot to
    the farthest such corner instead (the face seen, whose other foot may be hidden or
    below the view, so that :func:`foot_line` has no second foot to reach; where it has,
    the two sample the same line). ``corners_px`` K×2, ``v3`` homogeneous,
    ``focal_px``, ``centre`` the camera, ``camera_height_m`` above the floor. Not in the
    paper: the resume rule (:mod:`companion.control.supervisor`) keeps clear of these as of
    the feet themselves. Scalar arithmetic, as :func:`floor_contacts`: it runs for every
    obstacle of every frame in flight.
    """
    feet = [c for c in contacts if c.top_pixel is not None]
    if not feet or depth_m <= 0.0 or step_m <= 0.0:
        return []
    pts = [tuple(p) for p in np.asarray(corners_px, dtype=float).reshape(-1, 2).tolist()]
    down = down_direction(v3, focal_px, centre)
    (fx, fy, fz), (rx, ry, rz) = _floor_axes(down)
    cx, cy = float(centre[0]), float(centre[1])
    v3h = [float(t) for t in np.asarray(v3, dtype=float).reshape(3)]
    axes = [[float(t) for t in o] for o in np.asarray(ovps, dtype=float)[:2]]
    on_face = math.sin(math.radians(FACE_TOL_DEG))
    # Each corner's vertical line, through V3.
    verticals = [_cross((x, y, 1.0), v3h) for x, y in pts]
    out: list[tuple[float, float]] = []
    for foot in feet:
        low, top = foot.pixel, foot.top_pixel
        fa, fr = foot.ahead_right_m
        for ovp in axes:
            # The axis on the floor (ahead, right): the OVP's direction without its down part.
            ox, oy, oz = ovp[0] - ovp[2] * cx, ovp[1] - ovp[2] * cy, ovp[2] * focal_px
            a, b = ox * fx + oy * fy + oz * fz, ox * rx + oy * ry + oz * rz
            n = math.hypot(a, b)
            if n < 1e-12:
                continue
            a, b = a / n, b / n
            if a * fa + b * fr < 0.0:  # the direction leading away from the camera
                a, b = -a, -b
            # The corners seen on this face: where their vertical edges meet its foot.
            face = _cross((low[0], low[1], 1.0), ovp)
            meets = []
            for c, vertical in zip(pts, verticals, strict=True):
                if c in (low, top) or not (_passes_through(c, low, ovp, on_face)
                                           or _passes_through(c, top, ovp, on_face)):
                    continue
                q = _cross(face, vertical)
                if abs(q[2]) >= 1e-12:
                    meets.append((q[0] / q[2], q[1] / q[2]))
            along = [(g.ahead_right_m[0] - fa) * a + (g.ahead_right_m[1] - fr) * b
                     for g in floor_points(np.array(meets).reshape(-1, 2), down, focal_px,
                                           centre, camera_height_m) if g is not None]
            # A corner on the near side: the face seen ends at this foot, back to it; else
            # the floor behind, depth_m deep or to the farthest corner seen on the face.
            near = min(along, default=0.0)
            reach = near if near < -step_m else max([depth_m, *along])
            out += _between((fa, fr), (fa + a * reach, fr + b * reach), step_m)
    return out


def obstacle_contact(corners_px: np.ndarray, v3: np.ndarray, focal_px: float,
                     centre: np.ndarray, camera_height_m: float) -> FloorContact | None:
    """The nearest of :func:`floor_contacts`, None without any."""
    contacts = floor_contacts(corners_px, v3, focal_px, centre, camera_height_m)
    return min(contacts, key=lambda c: c.range_m) if contacts else None


def path_distance(obstacles: Iterable[Sequence[FloorContact]], half_width_m: float
                  ) -> float:
    """How far ahead (m, along the camera's forward direction on the floor) the nearest
    measured floor contact lies within the corridor ``|lateral| <= half_width_m`` the
    vehicle flies through; ``math.inf`` when none does (the measured obstacles are beside
    the path).

    ``obstacles``: per obstacle its contacts sorted by bearing (:func:`floor_contacts`);
    the floor edge between two neighbours is one face's foot, clipped to the corridor. An
    obstacle's part beyond its outermost visible foot is not known, so not counted.
    """
    best = math.inf
    for contacts in obstacles:
        pts = [c.ahead_right_m for c in contacts]
        for x, y in pts:
            if abs(y) <= half_width_m:
                best = min(best, x)
        for (x1, y1), (x2, y2) in zip(pts, pts[1:], strict=False):
            for edge_y in (-half_width_m, half_width_m):  # where the foot crosses the edges
                if (y1 - edge_y) * (y2 - edge_y) < 0:
                    best = min(best, x1 + (x2 - x1) * (edge_y - y1) / (y2 - y1))
    return best if best > 0 else math.inf
