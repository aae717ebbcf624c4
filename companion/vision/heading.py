"""Heading difference between the vehicle and an obstacle face (paper eqs. 9–11).

``M = [M_x, M_y]`` is the obstacle VP closest to the frame centre, in centred image
coordinates (origin at the image centre, x right, y **up** as in the paper's plots).
With ``D`` the "maximum depth" constant, which plays the part of a focal length:

- eq. 10  ``η = atan(M_x / D)``  (horizontal: the angle that steers)
- eq. 10  ``φ = atan(M_y / sqrt(D² + M_x²))``  (vertical)
- eq. 11  ``D_t = [η_t, φ_t] ≈ η_t``

Sign: η > 0 ⇔ M right of the centre ⇔ turn right (positive yaw rate, body FRD / NED).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Heading", "closest_to_centre", "heading_from_vp"]


@dataclass(frozen=True)
class Heading:
    """``eta_deg``, ``phi_deg`` of eq. 10, and ``m_px`` = (M_x, M_y) (None at infinity)."""

    eta_deg: float
    phi_deg: float
    m_px: tuple[float, float] | None


def closest_to_centre(vps: np.ndarray, centre: np.ndarray) -> int:
    """Index of the homogeneous point in ``vps`` (K×3) nearest the centre (eq. 9's M).

    Points at infinity are infinitely far; compared without dividing by ``w``.
    """
    cx, cy = float(centre[0]), float(centre[1])
    best = best_offset = best_w = None
    for k, (x, y, w) in enumerate(np.atleast_2d(vps).tolist()):
        offset = math.hypot(x - w * cx, y - w * cy)
        # distance = offset / |w|; compare offset_k · |w_best| without forming the ratio.
        if best is None or offset * best_w < best_offset * abs(w):
            best, best_offset, best_w = k, offset, abs(w)
    return best


def heading_from_vp(vp: np.ndarray, centre: np.ndarray, depth_px: float) -> Heading:
    """η and φ of eq. 10 for a homogeneous pixel point ``vp`` (finite or at infinity).

    Inputs: ``vp`` 3-vector; ``centre`` the image centre in pixels; ``depth_px`` = D.
    For a VP at infinity η and φ are the limits (±90° for a horizontal direction).
    """
    x, y, w = (float(c) for c in vp)
    if w < 0:
        x, y, w = -x, -y, -w
    mx = x - w * float(centre[0])  # M_x · w
    my = -(y - w * float(centre[1]))  # M_y · w, y up
    eta = math.degrees(math.atan2(mx, w * depth_px))
    phi = math.degrees(math.atan2(my, math.hypot(w * depth_px, mx)))
    m = (mx / w, my / w) if w > 1e-12 else None
    return Heading(eta, phi, m)
