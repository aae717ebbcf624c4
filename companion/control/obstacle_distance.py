"""Floor contacts → MAVLink OBSTACLE_DISTANCE (message 330), as PX4's Collision Prevention
consumes it from a companion computer.

The camera sees a wedge of directions ahead; it is cut into sectors of ``increment_deg``
centred on the optical axis (``frame`` MAV_FRAME_BODY_FRD, ``angle_offset`` the bearing
of the first sector, clockwise positive, as PX4 reads it). A sector holds the distance to
the nearest floor contact measured in it: an obstacle's foot corner, or the face between
two foot corners of one obstacle (a straight edge on the floor, intersected along the
sector's central bearing). Every other sector is UINT16_MAX, *unknown*: the method
measures obstacles only, so a sector without one is not declared free. Pure functions.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from companion.vision.pipeline import Estimate
from companion.vision.ranging import FloorContact

__all__ = ["ObstacleDistance", "obstacle_distance", "from_estimate", "unknown", "UNKNOWN",
           "SECTORS"]

UNKNOWN = 65535  # UINT16_MAX: unknown / not used, as MAVLink defines it
SECTORS = 72  # the message's fixed array length
MAV_FRAME_BODY_FRD = 12
MAV_DISTANCE_SENSOR_UNKNOWN = 4


@dataclass(frozen=True)
class ObstacleDistance:
    """One OBSTACLE_DISTANCE: ``distances_cm`` 72 values; ``increment_deg`` sector width;
    ``angle_offset_deg`` bearing of sector 0's centre; ``min_distance_cm``,
    ``max_distance_cm`` what the method can measure from this height and lens."""

    distances_cm: tuple[int, ...]
    increment_deg: float
    angle_offset_deg: float
    min_distance_cm: int
    max_distance_cm: int

    def mavlink_fields(self, time_usec: int) -> dict:
        """The message's fields by their MAVLink names."""
        return {
            "time_usec": int(time_usec),
            "sensor_type": MAV_DISTANCE_SENSOR_UNKNOWN,
            "distances": list(self.distances_cm),
            "increment": int(round(self.increment_deg)),
            "min_distance": self.min_distance_cm,
            "max_distance": self.max_distance_cm,
            "increment_f": float(self.increment_deg),
            "angle_offset": float(self.angle_offset_deg),
            "frame": MAV_FRAME_BODY_FRD,
        }

    def sector_bearing_deg(self, i: int) -> float:
        return self.angle_offset_deg + i * self.increment_deg


def _along(c1: FloorContact, c2: FloorContact, bearing_deg: float) -> float | None:
    """Distance along ``bearing_deg`` to the floor segment between two contacts, None if
    the bearing misses it."""
    (x1, y1), (x2, y2) = c1.ahead_right_m, c2.ahead_right_m
    b = math.radians(bearing_deg)
    ux, uy = math.cos(b), math.sin(b)
    dx, dy = x2 - x1, y2 - y1
    den = ux * dy - uy * dx
    if abs(den) < 1e-12:
        return None
    t = (x1 * dy - y1 * dx) / den  # along the ray
    s = (x1 * uy - y1 * ux) / den  # along the segment, 0..1
    return t if t > 0 and -1e-9 <= s <= 1 + 1e-9 else None


def obstacle_distance(obstacles: Iterable[Sequence[FloorContact]], hfov_deg: float,
                      vfov_deg: float, camera_height_m: float, focal_px: float,
                      increment_deg: float = 5.0) -> ObstacleDistance:
    """Sectors across the camera's ``hfov_deg`` from each obstacle's floor contacts
    (sorted by bearing, as :func:`~companion.vision.ranging.floor_contacts` gives them).

    ``min_distance``: the nearest floor a level camera sees (the bottom of ``vfov_deg``);
    ``max_distance``: where one pixel of the contact's row is 10 % of the range
    (0.1 · h · f), at most 20 m. A contact beyond it leaves its sector unknown: MAVLink's
    max + 1 would tell PX4 the sector is free, and a foot that far is as likely a wall's
    feature near the horizon as a real obstacle.
    """
    n = max(1, min(SECTORS, int(hfov_deg // increment_deg)))
    offset = -(n - 1) / 2.0 * increment_deg
    min_m = camera_height_m / math.tan(math.radians(max(vfov_deg, 1.0) / 2.0))
    max_m = min(0.1 * camera_height_m * focal_px, 20.0)
    best = [math.inf] * n

    def put(i: int, d: float) -> None:
        if 0 <= i < n:
            best[i] = min(best[i], d)

    for contacts in obstacles:
        contacts = list(contacts)
        for c in contacts:
            put(round((c.bearing_deg - offset) / increment_deg), c.range_m)
        for c1, c2 in zip(contacts, contacts[1:], strict=False):
            for i in range(n):
                d = _along(c1, c2, offset + i * increment_deg)
                if d is not None:
                    put(i, d)
    cm = []
    for d in best:
        if math.isinf(d) or d > max_m:
            cm.append(UNKNOWN)
        else:
            cm.append(int(round(max(d, min_m) * 100)))
    return ObstacleDistance(tuple(cm + [UNKNOWN] * (SECTORS - n)), float(increment_deg),
                            offset, int(round(min_m * 100)), int(round(max_m * 100)))


def from_estimate(est: Estimate, increment_deg: float = 5.0) -> ObstacleDistance | None:
    """The sectors of one frame's :class:`Estimate`, None without the camera height."""
    if not est.camera_height_m or est.focal_px <= 0:
        return None
    hfov = 2.0 * math.degrees(math.atan(est.width / 2.0 / est.focal_px))
    vfov = 2.0 * math.degrees(math.atan(est.height / 2.0 / est.focal_px))
    return obstacle_distance(est.obstacle_contacts, hfov, vfov, est.camera_height_m,
                             est.focal_px, increment_deg)


def unknown(last: ObstacleDistance | None, increment_deg: float = 5.0) -> ObstacleDistance:
    """All sectors unknown (stale vision, no height yet): the stream PX4 needs goes on
    without claiming anything."""
    if last is None:
        return ObstacleDistance((UNKNOWN,) * SECTORS, float(increment_deg), 0.0, 0, 0)
    return ObstacleDistance((UNKNOWN,) * SECTORS, last.increment_deg, last.angle_offset_deg,
                            last.min_distance_cm, last.max_distance_cm)
