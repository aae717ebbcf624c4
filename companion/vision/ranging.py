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

from companion.vision.geometry import direction_of

__all__ = ["FloorContact", "floor_point", "floor_contacts", "obstacle_contact", "down_direction",
           "path_distance"]

VERTICAL_EDGE_TOL_DEG = 2.0
"""two corners are on one vertical edge when their line points at V3 within this"""

MIN_DEPRESSION_DEG = 1.0
"""a ray less than this below the horizon meets the floor too far away to trust"""


@dataclass(frozen=True)
class FloorContact:
    """Where something meets the floor: ``range_m`` horizontal distance from the camera,
    ``bearing_deg`` right of the camera's forward direction (projected on the floor),
    ``pixel`` the image point (x, y)."""

    range_m: float
    bearing_deg: float
    pixel: tuple[float, float]

    @property
    def ahead_right_m(self) -> tuple[float, float]:
        """The contact on the floor: metres ahead of the camera and to its right."""
        b = math.radians(self.bearing_deg)
        return self.range_m * math.cos(b), self.range_m * math.sin(b)


def down_direction(v3: np.ndarray, focal_px: float, centre: np.ndarray) -> np.ndarray:
    """Unit vector of the world's down direction in camera coordinates (x right, y down,
    z forward), from the vertical VP ``v3`` (homogeneous pixels)."""
    d = direction_of(np.asarray(v3, dtype=float), focal_px, centre).reshape(3)
    return d if d[1] >= 0 else -d  # the camera is upright: down is down in the image


def floor_point(pixel, down: np.ndarray, focal_px: float, centre: np.ndarray,
                camera_height_m: float) -> FloorContact | None:
    """The floor point seen at ``pixel`` (x, y), None above or too near the horizon.

    Inputs: ``down`` from :func:`down_direction`; ``focal_px``, ``centre`` the camera;
    ``camera_height_m`` above the floor.
    """
    x, y = float(pixel[0]), float(pixel[1])
    r = np.array([(x - centre[0]) / focal_px, (y - centre[1]) / focal_px, 1.0])
    r /= np.linalg.norm(r)
    s = float(r @ down)  # sine of the ray's depression below the horizon
    if s < math.sin(math.radians(MIN_DEPRESSION_DEG)):
        return None
    p = camera_height_m * r / s
    horizontal = p - (p @ down) * down
    fwd = np.array([0.0, 0.0, 1.0]) - down[2] * down
    fwd /= np.linalg.norm(fwd)
    right = np.cross(down, fwd)  # camera x, levelled: down × forward points right
    bearing = math.degrees(math.atan2(float(horizontal @ right), float(horizontal @ fwd)))
    return FloorContact(float(np.linalg.norm(horizontal)), bearing, (x, y))


def floor_contacts(corners_px: np.ndarray, v3: np.ndarray, focal_px: float,
                   centre: np.ndarray, camera_height_m: float) -> list[FloorContact]:
    """Every floor contact of an obstacle whose corner projections are ``corners_px``
    (K×2): the lower corner of each pair of its corners on one line through V3, seen on
    the floor, sorted by bearing. Empty when no two corners share a vertical edge."""
    pts = np.atleast_2d(np.asarray(corners_px, dtype=float))
    down = down_direction(v3, focal_px, centre)
    v = np.asarray(v3, dtype=float)
    tol = math.sin(math.radians(VERTICAL_EDGE_TOL_DEG))
    rays = [direction_of(np.array([x, y, 1.0]), focal_px, centre).reshape(3) for x, y in pts]
    lower = set()
    for i in range(len(pts)):
        for j in range(len(pts)):
            edge = pts[i] - pts[j]
            n = float(np.hypot(*edge))
            if i == j or n < 1.0:
                continue
            to_v3 = v[:2] - v[2] * pts[j]  # toward V3 from corner j (V3 may be at infinity)
            m = float(np.hypot(*to_v3))
            if m < 1e-12 or abs(edge[0] * to_v3[1] - edge[1] * to_v3[0]) / (n * m) > tol:
                continue  # not on one vertical line
            if float(rays[i] @ down) > float(rays[j] @ down):
                lower.add(i)  # i lies farther down than j: the foot of their edge
    out = [floor_point(pts[i], down, focal_px, centre, camera_height_m) for i in sorted(lower)]
    return sorted((c for c in out if c is not None), key=lambda c: c.bearing_deg)


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
