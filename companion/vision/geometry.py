"""Homogeneous points in the image plane and the 3-D directions they stand for.

Every point here is a homogeneous 3-vector, so vanishing points at infinity (``w = 0``)
are ordinary values: nothing divides by ``w``. Pixel coordinates put the centre of the
top-left pixel at (0, 0), x right, y down. These helpers turn the pipeline's VPs into
pixels, directions and angles; the per-segment geometry inside the stages (lines through
segments, intersections, a segment's consistency with a VP) is the inline C of
``_geometry.pxd``, with the same conventions.

All functions are pure and vectorised over a leading axis where that is natural.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "segment_lengths",
    "to_pixels",
    "direction_of",
    "point_of",
    "angle_between_directions_deg",
    "focal_from_orthogonal_vps",
    "principal_point",
]


def principal_point(width: int, height: int) -> np.ndarray:
    """Image centre in pixels, ``((W - 1) / 2, (H - 1) / 2)``: the origin of eq. 10."""
    return np.array([(width - 1) / 2.0, (height - 1) / 2.0])


def segment_lengths(segments: np.ndarray) -> np.ndarray:
    """Euclidean lengths ``l`` of segments (N×4 → N, pixels)."""
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    return np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1])


def to_pixels(point: np.ndarray) -> np.ndarray | None:
    """Pixel position ``(x, y)`` of a finite homogeneous point, ``None`` at infinity."""
    p = np.asarray(point, dtype=float)
    if abs(p[2]) < 1e-12 * max(1.0, float(np.abs(p[:2]).max())):
        return None
    return p[:2] / p[2]


def direction_of(point: np.ndarray, focal_px: float, centre: np.ndarray) -> np.ndarray:
    """Unit 3-D viewing direction ``K⁻¹ v`` of homogeneous image point(s) ``v``.

    ``K`` is a pinhole with focal ``focal_px`` and principal point ``centre``; camera
    axes are x right, y down, z forward. Works for points at infinity (``w = 0``).
    """
    p = np.asarray(point, dtype=float)
    d = np.empty(p.shape[:-1] + (3,))
    d[..., 0] = p[..., 0] - centre[0] * p[..., 2]
    d[..., 1] = p[..., 1] - centre[1] * p[..., 2]
    d[..., 2] = focal_px * p[..., 2]
    n = np.sqrt((d * d).sum(axis=-1, keepdims=True))
    return np.divide(d, n, out=np.zeros_like(d), where=n > 0)


def point_of(direction: np.ndarray, focal_px: float, centre: np.ndarray) -> np.ndarray:
    """Unit homogeneous pixel point(s) ``K d`` of 3-D camera direction(s) ``d``.

    The inverse of :func:`direction_of`; a direction with ``z = 0`` images at infinity.
    """
    d = np.asarray(direction, dtype=float)
    p = np.stack(
        [
            focal_px * d[..., 0] + centre[0] * d[..., 2],
            focal_px * d[..., 1] + centre[1] * d[..., 2],
            d[..., 2],
        ],
        axis=-1,
    )
    n = np.linalg.norm(p, axis=-1, keepdims=True)
    return np.divide(p, n, out=np.zeros_like(p), where=n > 0)


def angle_between_directions_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between undirected 3-D directions, in degrees within [0, 90]."""
    c = np.abs(np.sum(np.asarray(a) * np.asarray(b), axis=-1))
    return np.degrees(np.arccos(np.clip(c, 0.0, 1.0)))


def focal_from_orthogonal_vps(vp_a: np.ndarray, vp_b: np.ndarray,
                              centre: np.ndarray) -> float | None:
    """Focal length (pixels) that makes two finite VPs orthogonal directions.

    With square pixels and principal point ``centre``, orthogonal directions satisfy
    ``(a - c)·(b - c) + f² = 0``, so ``f = sqrt(-(a - c)·(b - c))``. ``None`` when either
    VP is at infinity or the VPs lie on the same side of the centre (no real solution).
    """
    a, b = np.asarray(vp_a, dtype=float), np.asarray(vp_b, dtype=float)
    if abs(a[2]) < 1e-12 or abs(b[2]) < 1e-12:
        return None
    q = -float((a[:2] / a[2] - centre) @ (b[:2] / b[2] - centre))
    return math.sqrt(q) if q > 0 else None
