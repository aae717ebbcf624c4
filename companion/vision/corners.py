"""Spatial-corner projections, their integrity Λ, and the non-Manhattan constraint.

A corner projection is three segments ``C = {L_s, L_n, L_r}`` meeting at one point
(paper eq. 2). ``p_c`` is the intersection of ``L_s`` and ``L_n``; with ``p``, ``l`` the
midpoint and length of a segment and ``d`` the Euclidean distance:

- eq. 3  ``Λ_LP = |d(p_c, p_s) − l_s/2| + |d(p_c, p_n) − l_n/2|``
- eq. 4  ``Λ_C  = Λ_LP + |d(p_c, p_r) − l_r/2|``

``Λ`` is 0 when ``p_c`` sits exactly on an endpoint of all three segments. Corners are
ranked by ``Λ_C`` and the best ``top_k`` kept (the paper keeps 100).

``L_r`` is the corner's vertical leg: candidates are grown from the endpoints of segments
assigned to V3, since both Table I and the pairing of eqs. 5–7 need one; this also keeps
the search linear in the number of segments near each vertical endpoint instead of cubic
in all segments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.vision._corners import corner_projections
from companion.vision._corners import loose_ends as _loose_ends
from companion.vision._vanishing import assign
from companion.vision.vanishing import V1, V2, V3

__all__ = ["CornerParams", "Corners", "find_corners", "loose_ends", "obstacle_legs",
           "table1_labels", "table1_mask"]


@dataclass(frozen=True)
class CornerParams:
    """Thresholds of the corner stage."""

    radius_px: float = 10.0  # segment endpoints within this of the corner point join it
    min_leg_angle_deg: float = 12.0  # L_s and L_n at least this far apart in the image
    min_vertical_leg_angle_deg: float = 2.5  # L_r at least this far from L_s and L_n
    leg_gap_frac: float = 0.15  # the vertical leg may stop this share of its length short
    leg_growth_px: float = 24.0  # legs grow up to this far along their edge to a junction
    manhattan_leg_deg: float = 1.5  # Table I: a leg is V1/V2 only if it points there this well
    manhattan_leg_residual_px: float = 2.0  # ... with endpoints at most this far off its line
    manhattan_leg_noise_px: float = 1.0  # or whatever its angle, endpoints this close to it
    top_k: int = 100  # corners kept after ranking by Λ_C (paper: top 100)


@dataclass(frozen=True)
class Corners:
    """Corner projections, best (smallest Λ_C) first.

    ``points_px`` K×2 corner points ``p_c``; ``s``, ``n``, ``r`` K indices into the
    segment array (``r`` the vertical leg); ``lambda_lp``, ``lambda_c`` K integrities in
    pixels (eqs. 3, 4).
    """

    points_px: np.ndarray
    s: np.ndarray
    n: np.ndarray
    r: np.ndarray
    lambda_lp: np.ndarray
    lambda_c: np.ndarray

    def __len__(self) -> int:
        return len(self.points_px)

    def take(self, idx: np.ndarray) -> Corners:
        """The corners at ``idx`` (an index array or boolean mask)."""
        return Corners(
            self.points_px[idx],
            self.s[idx],
            self.n[idx],
            self.r[idx],
            self.lambda_lp[idx],
            self.lambda_c[idx],
        )

    @staticmethod
    def empty() -> Corners:
        z = np.empty(0, int)
        return Corners(np.empty((0, 2)), z, z, z, np.empty(0), np.empty(0))


def find_corners(
    segments: np.ndarray, labels: np.ndarray, params: CornerParams | None = None
) -> Corners:
    """Corner projections ``{L_s, L_n, L_r}`` with ``L_r`` a V3 segment, ranked by Λ_C.

    Candidates: two non-vertical segments ``L_s``, ``L_n`` at least ``min_leg_angle_deg``
    apart with endpoints within ``radius_px`` of each other meet at ``p_c``, which must lie
    within ``radius_px`` of an end of each; the vertical leg ``L_r`` is the V3 segment,
    at least ``min_vertical_leg_angle_deg`` from both, whose line passes within
    ``radius_px / 2`` of ``p_c`` and whose nearer end is at most
    ``radius_px + leg_gap_frac · l_r`` from it (line detectors often stop short of a
    junction; eq. 4's third term charges that gap in the ranking), the one with the
    smallest such term.

    Inputs: ``segments`` N×4 pixels; ``labels`` N VP labels from
    :func:`companion.vision.vanishing.assign_segments`.
    Output: :class:`Corners`, at most ``top_k``, sorted by Λ_C ascending (eq. 4; ties in
    order of ``(L_s, L_n)``).
    """
    p = params or CornerParams()
    return Corners(*corner_projections(
        segments, labels, V3, p.radius_px, math.sin(math.radians(p.min_leg_angle_deg)),
        math.sin(math.radians(p.min_vertical_leg_angle_deg)), p.leg_gap_frac, p.top_k))


def loose_ends(segments: np.ndarray, radius_px: float,
               among: np.ndarray | None = None) -> np.ndarray:
    """Which segment ends meet no other segment's end within ``radius_px`` (N×2 bool).

    Only these may be grown toward a junction
    (:func:`~companion.vision.lines.extend_segments`): an end that already meets another
    is at its junction, and growing it could carry it past the corner, where the two legs
    would no longer meet. With ``among`` (N bool) only those segments count, and the
    others are not loose: the pipeline passes the segments that can make a Table-I corner
    (verticals and obstacle legs), since a room line ending on an obstacle's edge is the
    obstacle hiding it (a T-junction), not the obstacle's corner.
    """
    return _loose_ends(segments, radius_px, among)


def table1_labels(segments: np.ndarray, vps: np.ndarray, params: CornerParams) -> np.ndarray:
    """Segment labels for Table I: V1 or V2 only where a leg is Manhattan beyond doubt.

    A leg is V1/V2 when it points at that VP within ``manhattan_leg_deg`` with endpoints
    within ``manhattan_leg_residual_px`` of the line to it, or, whatever its angle, within
    ``manhattan_leg_noise_px``: a short leg's direction is too noisy to show a small
    rotation (1 px at the end of a 26 px leg is 4°), so a picture frame's short edges must
    not pass for a rotated box's. Inputs: ``segments`` N×4 pixels, ``vps`` 3×3 layout VPs
    (V1, V2, V3). Returns N labels as :func:`~companion.vision.vanishing.assign_segments`.
    """
    labels, _ = assign(segments, vps, params.manhattan_leg_deg, params.manhattan_leg_residual_px)
    near, _ = assign(segments, np.asarray(vps)[[V1, V2]], 90.0, params.manhattan_leg_noise_px)
    return np.where(near >= 0, near, labels)


def obstacle_legs(labels: np.ndarray, strict_labels: np.ndarray) -> np.ndarray:
    """Which segments may be horizontal edges of a rotated obstacle (Table I): neither V3
    nor V1/V2 beyond doubt (N bool).

    ``labels`` are the ordinary segment labels; ``strict_labels`` those of
    :func:`table1_labels`, with the tight ``manhattan_leg_*`` thresholds. Near the horizon
    every horizontal line points within a few degrees of every horizontal VP, so an
    obstacle's edge often passes the ordinary test for V1 too; a leg is ruled Manhattan
    only when it points at V1 or V2 tightly. The OVP test of eq. 8 then rejects pairs
    whose legs were Manhattan after all.
    """
    strict = np.asarray(strict_labels)
    return (strict != V1) & (strict != V2) & (np.asarray(labels) != V3)


def table1_mask(corners: Corners, labels: np.ndarray, legs: np.ndarray) -> np.ndarray:
    """Paper Table I: the corners of a non-Manhattan obstacle standing on the floor.

    ``L_s`` and ``L_n`` belong to neither V1 nor V2 (nor V3): they are horizontal edges
    of a rotated object (``legs``, from :func:`obstacle_legs`); ``L_r`` belongs to V3
    (``labels``): a vertical edge. Returns a K bool mask.
    """
    return legs[corners.s] & legs[corners.n] & (np.asarray(labels)[corners.r] == V3)
