"""Homogeneous points and lines in the image plane.

Every point and line here is a homogeneous 3-vector, so vanishing points at infinity
(``w = 0``) and parallel segments are ordinary values: nothing divides by ``w``.
Pixel coordinates put the centre of the top-left pixel at (0, 0), x right, y down.

All functions are pure and vectorised over a leading axis where that is natural.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "segment_lines",
    "segment_midpoints",
    "segment_lengths",
    "segment_directions",
    "intersect",
    "vp_consistency",
    "to_pixels",
    "direction_of",
    "endpoint_weights",
    "point_of",
    "horizon_line",
    "angle_between_directions_deg",
    "principal_point",
]


def principal_point(width: int, height: int) -> np.ndarray:
    """Image centre in pixels, ``((W - 1) / 2, (H - 1) / 2)``: the origin of eq. 10."""
    return np.array([(width - 1) / 2.0, (height - 1) / 2.0])


def segment_midpoints(segments: np.ndarray) -> np.ndarray:
    """Midpoints ``p`` of segments ``[x1, y1, x2, y2]`` (N×4 → N×2, pixels)."""
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    return 0.5 * (s[:, 0:2] + s[:, 2:4])


def segment_lengths(segments: np.ndarray) -> np.ndarray:
    """Euclidean lengths ``l`` of segments (N×4 → N, pixels)."""
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    return np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1])


def segment_directions(segments: np.ndarray) -> np.ndarray:
    """Unit direction vectors of segments (N×4 → N×2); zero-length segments give (0, 0)."""
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    d = s[:, 2:4] - s[:, 0:2]
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.divide(d, n, out=np.zeros_like(d), where=n > 0)


def segment_lines(segments: np.ndarray) -> np.ndarray:
    """Homogeneous lines through segments (N×4 → N×3), scaled so that ``a² + b² = 1``.

    With that scaling ``line @ [x, y, 1]`` is the signed distance in pixels from the
    point to the line.
    """
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    x1, y1, x2, y2 = s.T
    # [x1, y1, 1] × [x2, y2, 1], written out: np.cross costs more than the arithmetic.
    lines = np.column_stack([y1 - y2, x2 - x1, x1 * y2 - x2 * y1])
    n = np.hypot(lines[:, 0], lines[:, 1])[:, None]
    return np.divide(lines, n, out=np.zeros_like(lines), where=n > 0)


def intersect(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection of homogeneous lines (or the line through two points): ``a × b``.

    Parallel lines meet at a point at infinity (``w = 0``); the result is scaled to unit
    norm so that far and infinite points stay well conditioned.
    """
    a, b = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    # Written out: np.cross and np.linalg.norm cost more than this arithmetic on small arrays.
    p = np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                  a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                  a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)
    n = np.sqrt((p * p).sum(axis=-1, keepdims=True))
    return np.divide(p, n, out=np.zeros_like(p), where=n > 0)


def to_pixels(point: np.ndarray) -> np.ndarray | None:
    """Pixel position ``(x, y)`` of a finite homogeneous point, ``None`` at infinity."""
    p = np.asarray(point, dtype=float)
    if abs(p[2]) < 1e-12 * max(1.0, float(np.abs(p[:2]).max())):
        return None
    return p[:2] / p[2]


def vp_consistency(segments: np.ndarray, vp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How well each segment points at a vanishing point (finite or at infinity).

    For a segment with midpoint ``m`` and direction ``u`` the direction from ``m`` to the
    homogeneous point ``v = (x, y, w)`` is ``(x, y) − w·m`` (no division by ``w``). The
    returned angle is between ``u`` and that direction, folded to [0, 90] degrees; the
    residual is how far, in pixels, the segment's endpoints stray from the line joining
    its midpoint to ``v`` (``sin(angle) · length / 2``).

    Returns ``(angle_deg, residual_px)``, each of shape (N,), or (K, N) for K×3 ``vp``
    (K points at once). A segment whose midpoint coincides with ``v`` gets 90° (it
    carries no evidence for ``v``).
    """
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    v = np.asarray(vp, dtype=float)
    # Written out on columns: this runs many times per frame on small arrays, where
    # each numpy call's overhead costs more than its arithmetic.
    ux, uy = s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]
    tx = v[..., 0, None] - v[..., 2, None] * (0.5 * (s[:, 0] + s[:, 2]))
    ty = v[..., 1, None] - v[..., 2, None] * (0.5 * (s[:, 1] + s[:, 3]))
    lu = np.hypot(ux, uy)
    denom = lu * np.hypot(tx, ty)
    sin = np.abs(ux * ty - uy * tx) / np.maximum(denom, 1e-300)
    sin[denom <= 1e-12] = 1.0
    np.minimum(sin, 1.0, out=sin)
    return np.degrees(np.arcsin(sin)), sin * lu / 2.0


def endpoint_weights(segments: np.ndarray, vp: np.ndarray) -> np.ndarray:
    """Weights turning the algebraic residual ``l·v`` of a VP fit into endpoint residuals.

    A segment of length ``L`` whose midpoint ``m`` sees ``v = (x, y, w)`` (unit norm)
    along ``t = (x, y) − w·m`` strays from the line to ``v`` by ``|l·v| · (L/2) / |t|`` at
    its ends (``l`` as :func:`segment_lines`), so minimising ``Σ (L/|t|)² (l·v)²``
    minimises the endpoint residuals: segments near a finite VP do not dominate and
    distant ones still count. Shape (N,), or (K, N) for K×3 ``vp``.
    """
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    v = np.asarray(vp, dtype=float)
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    t = np.hypot(v[..., 0, None] - v[..., 2, None] * (0.5 * (s[:, 0] + s[:, 2])),
                 v[..., 1, None] - v[..., 2, None] * (0.5 * (s[:, 1] + s[:, 3])))
    return (np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]) / np.maximum(t, 1e-12)) ** 2


def direction_of(point: np.ndarray, focal_px: float, centre: np.ndarray) -> np.ndarray:
    """Unit 3-D viewing direction ``K⁻¹ v`` of homogeneous image point(s) ``v``.

    ``K`` is a pinhole with focal ``focal_px`` and principal point ``centre``; camera
    axes are x right, y down, z forward. Works for points at infinity (``w = 0``).
    """
    p = np.asarray(point, dtype=float)
    d = np.stack(
        [
            p[..., 0] - centre[0] * p[..., 2],
            p[..., 1] - centre[1] * p[..., 2],
            focal_px * p[..., 2],
        ],
        axis=-1,
    )
    n = np.linalg.norm(d, axis=-1, keepdims=True)
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


def horizon_line(vertical_vp: np.ndarray, focal_px: float, centre: np.ndarray) -> np.ndarray:
    """The horizon: image line of all directions orthogonal to the vertical VP.

    ``l = K⁻ᵀ K⁻¹ v3``, returned scaled like :func:`segment_lines` (``a² + b² = 1``) so
    that ``l · [x, y, 1]`` is a distance in pixels.
    """
    d = direction_of(vertical_vp, focal_px, centre)
    line = np.array(
        [d[0] / focal_px, d[1] / focal_px, d[2] - (centre[0] * d[0] + centre[1] * d[1]) / focal_px]
    )
    n = np.hypot(line[0], line[1])
    return line / n if n > 0 else np.array([0.0, 0.0, 1.0])


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
