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

from dataclasses import dataclass, replace

import numpy as np

from companion.vision.geometry import (
    intersect,
    segment_directions,
    segment_lengths,
    segment_lines,
    segment_midpoints,
)
from companion.vision.vanishing import V1, V2, V3, VPParams, assign_segments

__all__ = ["CornerParams", "Corners", "find_corners", "integrity", "loose_ends", "table1_labels",
           "table1_mask"]


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


def integrity(corner_px: np.ndarray, midpoints: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Σ_k |d(p_c, p_k) − l_k/2| over the legs of each corner (eqs. 3 and 4).

    ``corner_px`` K×2; ``midpoints`` K×L×2 and ``lengths`` K×L for the L legs of each
    corner (L = 2 gives Λ_LP, L = 3 gives Λ_C). Returns K values in pixels.
    """
    d = np.linalg.norm(midpoints - corner_px[:, None, :], axis=2)
    return np.abs(d - lengths / 2.0).sum(axis=1)


def find_corners(
    segments: np.ndarray, labels: np.ndarray, params: CornerParams | None = None
) -> Corners:
    """Corner projections ``{L_s, L_n, L_r}`` with ``L_r`` a V3 segment, ranked by Λ_C.

    Candidates: two non-vertical segments ``L_s``, ``L_n`` with endpoints within
    ``radius_px`` of each other meet at ``p_c``; the vertical leg ``L_r`` is the V3
    segment whose line passes within ``radius_px / 2`` of ``p_c`` and whose nearer end
    is at most ``radius_px + leg_gap_frac · l_r`` from it (line detectors often stop
    short of a junction; eq. 4's third term charges that gap in the ranking).

    Inputs: ``segments`` N×4 pixels; ``labels`` N VP labels from
    :func:`companion.vision.vanishing.assign_segments`.
    Output: :class:`Corners`, at most ``top_k``, sorted by Λ_C ascending (eq. 4).
    """
    p = params or CornerParams()
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    labels = np.asarray(labels)
    verticals = np.flatnonzero(labels == V3)
    others = np.flatnonzero(labels != V3)
    if len(verticals) == 0 or len(others) < 2:
        return Corners.empty()

    lines = segment_lines(s)
    mids = segment_midpoints(s)
    lengths = segment_lengths(s)
    dirs = segment_directions(s)
    min_sin = np.sin(np.radians(p.min_leg_angle_deg))
    ends = s.reshape(-1, 2, 2)

    # 1. L_s, L_n: non-vertical segments whose endpoints meet.
    i, j = _meeting_pairs(ends[others], p.radius_px)
    si, ni = others[i], others[j]
    apart = _sin_between(dirs[si], dirs[ni]) >= min_sin
    si, ni = si[apart], ni[apart]
    pc_h = intersect(lines[si], lines[ni])
    finite = np.abs(pc_h[:, 2]) > 1e-12
    si, ni, pc_h = si[finite], ni[finite], pc_h[finite]
    pc = pc_h[:, :2] / pc_h[:, 2:3]
    # p_c must sit at an end of both legs, not along their extensions or interiors.
    at_ends = (_end_distance(ends[si], pc) <= p.radius_px) & (
        _end_distance(ends[ni], pc) <= p.radius_px
    )
    si, ni, pc = si[at_ends], ni[at_ends], pc[at_ends]
    if len(pc) == 0:
        return Corners.empty()

    # 2. L_r: the V3 segment through p_c with the smallest eq.-4 term (P×V).
    vl = lines[verticals]
    perp = np.abs(pc @ vl[:, :2].T + vl[None, :, 2])
    term = np.abs(
        np.linalg.norm(pc[:, None, :] - mids[verticals][None], axis=2)
        - lengths[verticals][None] / 2.0
    )
    allowed = p.radius_px + p.leg_gap_frac * lengths[verticals][None]
    beyond_or_at_end = _end_distance(ends[verticals][None], pc[:, None, :]) <= allowed
    ok = (perp <= p.radius_px / 2.0) & beyond_or_at_end
    min_sin_r = np.sin(np.radians(p.min_vertical_leg_angle_deg))
    ok &= _sin_between(dirs[si][:, None, :], dirs[verticals][None]) >= min_sin_r
    ok &= _sin_between(dirs[ni][:, None, :], dirs[verticals][None]) >= min_sin_r
    cost = np.where(ok, term, np.inf)
    best = np.argmin(cost, axis=1)
    has = np.isfinite(cost[np.arange(len(pc)), best])
    si, ni, pc, ri = si[has], ni[has], pc[has], verticals[best[has]]
    if len(pc) == 0:
        return Corners.empty()

    legs = np.stack([si, ni, ri], axis=1)
    lam_lp = integrity(pc, mids[legs[:, :2]], lengths[legs[:, :2]])
    lam_c = lam_lp + integrity(pc, mids[legs[:, 2:]], lengths[legs[:, 2:]])
    order = np.argsort(lam_c, kind="stable")[: p.top_k]
    return Corners(pc[order], si[order], ni[order], ri[order], lam_lp[order], lam_c[order])


def _meeting_pairs(seg_ends: np.ndarray, radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``i < j`` of segments (S×2×2 ends) with an end of each within ``radius_px``.

    Pairs come out sorted by (i, j).
    """
    a, b = _close_ends(seg_ends, radius_px)
    sa, sb = a // 2, b // 2
    lo, hi = np.minimum(sa, sb), np.maximum(sa, sb)
    key = np.unique((lo * len(seg_ends) + hi)[lo != hi])
    return key // len(seg_ends), key % len(seg_ends)


def _close_ends(seg_ends: np.ndarray, radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of endpoints (flat indices ``2·segment + end``) at most ``radius_px`` apart.

    A sweep along x: after sorting the 2·S endpoints by x only those less than
    ``radius_px`` apart in x are compared, so the cost grows with the number of close
    pairs, not with S².
    """
    pts = seg_ends.reshape(-1, 2)
    order = np.argsort(pts[:, 0], kind="stable")
    xs = pts[order, 0]
    stop = np.searchsorted(xs, xs + radius_px, side="right")
    counts = stop - np.arange(len(xs)) - 1
    a = np.repeat(np.arange(len(xs)), counts)
    b = a + 1 + np.arange(len(a)) - np.repeat(np.cumsum(counts) - counts, counts)
    a, b = order[a], order[b]
    d = pts[a] - pts[b]
    close = d[:, 0] ** 2 + d[:, 1] ** 2 <= radius_px**2
    return a[close], b[close]


def loose_ends(segments: np.ndarray, radius_px: float) -> np.ndarray:
    """Which segment ends meet no other segment's end within ``radius_px`` (N×2 bool).

    Only these may be grown toward a junction
    (:func:`~companion.vision.lines.extend_segments`): an end that already meets another
    is at its junction, and growing it could carry it past the corner, where the two legs
    would no longer meet.
    """
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    loose = np.ones(2 * len(s), bool)
    a, b = _close_ends(s.reshape(-1, 2, 2), radius_px)
    other = a // 2 != b // 2
    loose[a[other]] = False
    loose[b[other]] = False
    return loose.reshape(-1, 2)


def _sin_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|sin| of the angle between unit 2-D directions (broadcasting)."""
    return np.abs(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])


def _end_distance(seg_ends: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearer endpoint of its segment (…×2×2, …×2)."""
    near = np.hypot(seg_ends[..., 0, 0] - points[..., 0], seg_ends[..., 0, 1] - points[..., 1])
    far = np.hypot(seg_ends[..., 1, 0] - points[..., 0], seg_ends[..., 1, 1] - points[..., 1])
    return np.minimum(near, far)


def table1_labels(segments: np.ndarray, vps: np.ndarray, vp_params: VPParams,
                  params: CornerParams) -> np.ndarray:
    """Segment labels for Table I: V1 or V2 only where a leg is Manhattan beyond doubt.

    A leg is V1/V2 when it points at that VP within ``manhattan_leg_deg`` with endpoints
    within ``manhattan_leg_residual_px`` of the line to it, or, whatever its angle, within
    ``manhattan_leg_noise_px``: a short leg's direction is too noisy to show a small
    rotation (1 px at the end of a 26 px leg is 4°), so a picture frame's short edges must
    not pass for a rotated box's. Inputs: ``segments`` N×4 pixels, ``vps`` 3×3 layout VPs
    (V1, V2, V3). Returns N labels as :func:`~companion.vision.vanishing.assign_segments`.
    """
    strict = replace(vp_params, max_angle_deg=params.manhattan_leg_deg,
                     residual_px=params.manhattan_leg_residual_px)
    labels, _ = assign_segments(segments, vps, strict)
    within_noise = replace(vp_params, max_angle_deg=90.0, residual_px=params.manhattan_leg_noise_px)
    near, _ = assign_segments(segments, np.asarray(vps)[[V1, V2]], within_noise)
    return np.where(near >= 0, near, labels)


def table1_mask(corners: Corners, labels: np.ndarray, strict_labels: np.ndarray) -> np.ndarray:
    """Paper Table I: the corners of a non-Manhattan obstacle standing on the floor.

    ``L_s`` and ``L_n`` belong to neither V1 nor V2 (nor V3): they are horizontal edges
    of a rotated object; ``L_r`` belongs to V3: a vertical edge.

    ``labels`` are the ordinary segment labels; ``strict_labels`` those of
    :func:`table1_labels`, with the tight ``manhattan_leg_*`` thresholds. Near the horizon
    every horizontal line points within a few degrees of every horizontal VP, so an
    obstacle's edge often passes the ordinary test for V1 too; a leg is ruled Manhattan
    only when it points at V1 or V2 tightly. The OVP test of eq. 8 then rejects pairs
    whose legs were Manhattan after all. Returns a K bool mask.
    """
    labels = np.asarray(labels)
    strict = np.asarray(strict_labels)
    free_s = ~np.isin(strict[corners.s], (V1, V2)) & (labels[corners.s] != V3)
    free_n = ~np.isin(strict[corners.n], (V1, V2)) & (labels[corners.n] != V3)
    return free_s & free_n & (labels[corners.r] == V3)
