"""Layout vanishing points V1 (LMVP), V2, V3 and the segment → VP assignment (paper Fig. 2).

The paper takes the layout VPs from the authors' earlier work; this module uses a method
that needs no calibration beyond a rough focal length and never divides by zero:

1. **V3, vertical.** Near-vertical segments vote: every pairwise intersection of the
   longest ones, and the point at infinity straight down the image, is a hypothesis,
   scored MSAC-style by the length of the segments that point at it; the best is refined
   by least squares over its inliers.
2. **Horizontal VPs.** Every horizontal direction in the world images onto the horizon,
   the line polar to V3. Each remaining segment crosses the horizon at one point, which is
   the VP it would have if it were a horizontal edge; that point is a single angle θ (the
   azimuth of the 3-D direction). A length-weighted histogram of θ has a peak for each
   family of parallel horizontal edges: the room's two axes and every rotated obstacle's.
   Each peak is then refined without the horizon constraint, so a rough focal length
   only costs a slightly blurred histogram, not a biased VP.
3. **Layout.** V1, V2 are the best supported pair of horizontal VPs that are orthogonal
   within a tolerance (V2 is inferred from V1 when only one axis is seen); V1 (the LMVP)
   is the better supported of the two. Other peaks are kept as obstacle-VP candidates.

All VPs are homogeneous pixel coordinates (unit-norm 3-vectors); see
:mod:`companion.vision.geometry`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from companion.vision.geometry import (
    angle_between_directions_deg,
    endpoint_weights,
    point_of,
    segment_lengths,
    segment_lines,
    vp_consistency,
)

__all__ = [
    "VPParams",
    "LayoutVPs",
    "detect_layout_vps",
    "assign_segments",
    "NONE",
    "V1",
    "V2",
    "V3",
]

V1, V2, V3, NONE = 0, 1, 2, -1


@dataclass(frozen=True)
class VPParams:
    """Thresholds of the VP stage (pixels and degrees)."""

    residual_px: float = 2.0  # endpoint distance from the segment–VP line for an inlier
    max_angle_deg: float = 4.0  # and at most this angle between segment and VP direction
    vertical_max_tilt_deg: float = 25.0  # V3 candidates lean at most this far from image vertical
    vertical_hypothesis_segments: int = 30  # longest candidates whose pairs are V3 hypotheses
    vertical_max_camera_tilt_deg: float = 35.0  # V3 within this of the camera's down axis
    histogram_bin_deg: float = 0.5
    histogram_sigma_deg: float = 1.0
    peak_min_share: float = 0.04  # a horizontal peak holds >= this share of horizontal length
    max_horizontal_vps: int = 6
    orthogonal_tol_deg: float = 20.0  # V1 ⟂ V2 within this when the focal length is a guess
    known_focal_orthogonal_tol_deg: float = 10.0  # ... and when it is given
    min_vp_separation_deg: float = 3.0  # peaks closer than this are one VP


@dataclass(frozen=True)
class LayoutVPs:
    """Result of the layout-VP stage.

    ``vps``: 3×3, rows V1 (LMVP), V2, V3 as unit-norm homogeneous pixel coordinates.
    ``observed``: per row, whether segments support it (False: inferred or default).
    ``support_px``: summed length of the inlier segments of each layout VP.
    ``others``: K×3 further horizontal VPs (obstacle-VP candidates), ``others_support_px``.
    ``focal_px``: the focal length used to relate VPs in 3-D (orthogonality, horizon).
    """

    vps: np.ndarray
    observed: tuple[bool, bool, bool]
    support_px: np.ndarray
    others: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    others_support_px: np.ndarray = field(default_factory=lambda: np.empty(0))
    focal_px: float = 0.0
    centre: np.ndarray = field(default_factory=lambda: np.zeros(2))

    @property
    def found(self) -> bool:
        """True when both a vertical and a horizontal layout VP are backed by segments."""
        return self.observed[V3] and self.observed[V1]

    @property
    def usable_rows(self) -> tuple[int, ...]:
        """Rows of ``vps`` worth reporting: backed by segments, or inferred (V2 ⟂ V1, V3)
        within a found layout."""
        return tuple(i for i in range(3) if self.observed[i] or self.found)


def _to_normalised(segments: np.ndarray, centre: np.ndarray, focal: float) -> np.ndarray:
    s = np.asarray(segments, dtype=float).reshape(-1, 4).copy()
    s[:, [0, 2]] -= centre[0]
    s[:, [1, 3]] -= centre[1]
    return s / focal


def _inliers(norm_segs: np.ndarray, vp: np.ndarray, focal: float, p: VPParams) -> np.ndarray:
    angle, residual = vp_consistency(norm_segs, vp)
    return (angle <= p.max_angle_deg) & (residual * focal <= p.residual_px)


def _msac_score(norm_segs, vp, focal, p: VPParams) -> np.ndarray:
    """MSAC's truncated quadratic ``1 − r²`` per segment (r: endpoint residual over
    ``residual_px``); 0 for segments that fail the inlier test (angle or residual)."""
    angle, residual = vp_consistency(norm_segs, vp)
    r = residual * focal / p.residual_px
    ok = (angle <= p.max_angle_deg) & (r <= 1.0)
    return np.where(ok, 1.0 - r**2, 0.0)


def _msac_weights(norm_segs, lengths, vp, focal, p: VPParams) -> np.ndarray:
    """Support of ``vp``: each inlier's length times its MSAC score."""
    return lengths * _msac_score(norm_segs, vp, focal, p)


def _refine_weights(norm_segs, vp, focal, p: VPParams) -> np.ndarray:
    """Weights of :func:`_refine`: the MSAC score of each inlier times
    :func:`endpoint_weights`, so the fit minimises endpoint residuals (the quantity the
    inlier test bounds), not the algebraic ``l·v``."""
    return _msac_score(norm_segs, vp, focal, p) * endpoint_weights(norm_segs, vp)


def _refine(lines: np.ndarray, weights: np.ndarray) -> np.ndarray | None:
    """Least-squares VP of weighted lines: the unit v minimising Σ w (l·v)²."""
    vps, ok = _refine_many(lines, weights[None])
    return vps[0] if ok[0] else None


def _refine_many(lines: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_refine` for K weightings (K×N) at once: K×3 VPs, and K flags saying
    whether at least two lines carried weight (else that row is meaningless)."""
    a = np.matmul((weights[:, :, None] * lines[None]).transpose(0, 2, 1), lines)
    _, vecs = np.linalg.eigh(a)
    return vecs[:, :, 0], np.count_nonzero(weights > 0, axis=1) >= 2


def _vertical_vp(ns, lines, lengths, focal, p: VPParams):
    """V3 in normalised coordinates, its inlier mask, and whether segments back it."""
    tilt = np.degrees(np.arctan2(np.abs(ns[:, 2] - ns[:, 0]), np.abs(ns[:, 3] - ns[:, 1])))
    cand = np.flatnonzero(tilt <= p.vertical_max_tilt_deg)
    default = np.array([0.0, 1.0, 0.0])
    if len(cand) < 2:
        return default, np.zeros(len(ns), bool), False
    top = cand[np.argsort(-lengths[cand], kind="stable")[: p.vertical_hypothesis_segments]]
    i, j = np.triu_indices(len(top), k=1)
    hyps = np.cross(lines[top[i]], lines[top[j]])
    hyps = np.vstack([default, hyps])
    norms = np.linalg.norm(hyps, axis=1)
    hyps = hyps[norms > 1e-12] / norms[norms > 1e-12, None]
    # The camera is never pitched or rolled this far: V3 lies near the image's y axis,
    # far outside the frame. Converging floor lines must not pass for verticals.
    min_cos = np.cos(np.radians(p.vertical_max_camera_tilt_deg))
    hyps = hyps[np.abs(hyps[:, 1]) >= min_cos]
    # Score every hypothesis against every candidate at once (H × C). With midpoint m and
    # direction u of a candidate and h = (x, y, w) a hypothesis, the direction from m to h
    # is t = (x, y) − w·m; |u × t| and |t|² are both linear in products of h's entries,
    # so each is one small matrix product instead of H × C × 2 temporaries.
    cs, cl = ns[cand], lengths[cand]
    mid = 0.5 * (cs[:, 0:2] + cs[:, 2:4])
    u = (cs[:, 2:4] - cs[:, 0:2]) / cl[:, None]
    cross_rows = np.column_stack([-u[:, 1], u[:, 0], u[:, 1] * mid[:, 0] - u[:, 0] * mid[:, 1]])
    cross = np.abs(hyps @ cross_rows.T)
    h_sq = np.column_stack([hyps[:, 0] ** 2 + hyps[:, 1] ** 2, hyps[:, 0] * hyps[:, 2],
                            hyps[:, 1] * hyps[:, 2], hyps[:, 2] ** 2])
    m_sq = np.column_stack([np.ones(len(cs)), -2.0 * mid[:, 0], -2.0 * mid[:, 1],
                            (mid**2).sum(axis=1)])
    t_norm = np.sqrt(np.maximum(h_sq @ m_sq.T, 0.0))
    sin = np.where(t_norm > 1e-15, cross / np.maximum(t_norm, 1e-15), 1.0)
    r = sin * (cl * (focal / (2.0 * p.residual_px)))[None]
    ok = (r <= 1.0) & (sin <= np.sin(np.radians(p.max_angle_deg)))
    scores = np.where(ok, cl[None] * (1.0 - r**2), 0.0).sum(axis=1)
    best = hyps[int(np.argmax(scores))]
    not_cand = np.ones(len(ns), bool)
    not_cand[cand] = False
    for _ in range(2):
        w = _refine_weights(ns, best, focal, p)
        w[not_cand] = 0.0
        refined = _refine(lines, w)
        if refined is None:
            break
        best = refined
    inl = _inliers(ns, best, focal, p) & ~not_cand
    tilted = abs(best[1]) / np.linalg.norm(best) < min_cos
    if np.count_nonzero(inl) < 2 or tilted:
        return default, np.zeros(len(ns), bool), False
    if best[1] < 0 or (best[1] == 0 and best[2] < 0):
        best = -best
    return best, inl, True


def _horizon_basis(v3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal e1 (≈ image right) and e2 (≈ forward) spanning the horizontal plane."""
    d3 = v3 / np.linalg.norm(v3)
    e1 = np.array([1.0, 0.0, 0.0]) - d3[0] * d3
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e1, d3)
    if e2[2] < 0:
        e2 = -e2
    return e1, e2


def _azimuths(lines: np.ndarray, v3: np.ndarray, basis) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth θ ∈ [0°, 180°) of the horizon point of each line; validity mask.
    ``basis`` is :func:`_horizon_basis` of ``v3``."""
    e1, e2 = basis
    pts = np.cross(lines, v3)
    ok = np.linalg.norm(pts, axis=1) > 1e-9
    theta = np.degrees(np.arctan2(pts @ e1, pts @ e2)) % 180.0
    return theta, ok


def _direction_at(theta_deg: float, basis) -> np.ndarray:
    e1, e2 = basis
    t = np.radians(theta_deg)
    return np.sin(t) * e1 + np.cos(t) * e2


def _histogram_peaks(theta, weights, p: VPParams) -> list[float]:
    nbins = int(round(180.0 / p.histogram_bin_deg))
    hist = np.bincount(
        (theta / p.histogram_bin_deg).astype(int) % nbins, weights=weights, minlength=nbins
    )
    half = int(np.ceil(3 * p.histogram_sigma_deg / p.histogram_bin_deg))
    k = np.exp(
        -0.5 * (np.arange(-half, half + 1) * p.histogram_bin_deg / p.histogram_sigma_deg) ** 2
    )
    padded = np.concatenate([hist[-half:], hist, hist[:half]])
    smooth = np.convolve(padded, k, mode="same")[half:-half]
    total = smooth.sum()
    if total <= 0:
        return []
    is_peak = (smooth >= np.roll(smooth, 1)) & (smooth > np.roll(smooth, -1))
    idx = np.flatnonzero(is_peak & (smooth >= p.peak_min_share * total / (k.sum())))
    idx = idx[np.argsort(-smooth[idx])]
    return [float((i + 0.5) * p.histogram_bin_deg) for i in idx[: 2 * p.max_horizontal_vps]]


def detect_layout_vps(
    segments: np.ndarray,
    width: int,
    height: int,
    focal_px: float,
    params: VPParams | None = None,
) -> LayoutVPs:
    """Layout vanishing points V1 (LMVP), V2, V3 of a frame (paper §II-A, Fig. 2).

    Inputs: ``segments`` N×4 pixels; frame ``width``×``height``; ``focal_px`` a focal
    length guess in pixels (principal point at the frame centre).
    Output: :class:`LayoutVPs`. Never raises on degenerate input: with no segments all
    three rows are defaults (V3 straight down at infinity) and ``observed`` is all False.
    """
    p = params or VPParams()
    centre = np.array([(width - 1) / 2.0, (height - 1) / 2.0])
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    ns = _to_normalised(s, centre, focal_px)
    lines = segment_lines(ns)
    lengths = segment_lengths(s)

    v3, v3_inl, v3_ok = _vertical_vp(ns, lines, lengths, focal_px, p)

    # Horizontal VP candidates from the horizon histogram, refined and merged.
    rest = ~v3_inl
    basis = _horizon_basis(v3)
    theta, valid = _azimuths(lines, v3, basis)
    use = rest & valid
    cands: list[tuple[np.ndarray, float]] = []
    # Every histogram peak refined at once (K×N weights), then taken in order of height.
    peak_vps = np.array([_direction_at(pk, basis) for pk in
                         _histogram_peaks(theta[use], lengths[use], p)]).reshape(-1, 3)
    for _ in range(2):
        refined, ok = _refine_many(lines, _refine_weights(ns, peak_vps, focal_px, p) * rest)
        peak_vps = np.where(ok[:, None], refined, peak_vps)
    supports = (_msac_weights(ns, lengths, peak_vps, focal_px, p) * rest).sum(axis=1)
    for vp, support in zip(peak_vps, supports.tolist(), strict=True):
        if support <= 0:
            continue
        vp = vp if vp[2] >= 0 else -vp
        if any(angle_between_directions_deg(vp, c) < p.min_vp_separation_deg for c, _ in cands):
            continue
        # A "horizontal" VP that is really the vertical one is not a horizontal VP.
        if angle_between_directions_deg(vp, v3) < 45.0:
            continue
        cands.append((vp, support))
        if len(cands) >= p.max_horizontal_vps:
            break

    layout, others = _choose_layout(cands, v3, p)
    if layout is None:
        v1, v2 = _direction_at(90.0, basis), _direction_at(0.0, basis)
        obs, sup = (False, False), (0.0, 0.0)
    else:
        (v1, s1), (v2, s2), v2_seen = layout
        obs, sup = (True, v2_seen), (s1, s2)

    vps_norm = np.vstack([v1, v2, v3])
    v3_support = float(lengths[v3_inl].sum())
    return LayoutVPs(
        vps=point_of(vps_norm, focal_px, centre),
        observed=(obs[0], obs[1], v3_ok),
        support_px=np.array([sup[0], sup[1], v3_support]),
        others=point_of(np.array([c for c, _ in others]).reshape(-1, 3), focal_px, centre),
        others_support_px=np.array([w for _, w in others]),
        focal_px=float(focal_px),
        centre=centre,
    )


def _choose_layout(cands, v3, p: VPParams):
    """Best-supported (near-)orthogonal pair of horizontal VPs; the rest are 'others'."""
    if not cands:
        return None, []
    best, best_score = None, -1.0
    for i, (a, sa) in enumerate(cands):
        for j, (b, sb) in enumerate(cands):
            if j <= i:
                continue
            if abs(90.0 - angle_between_directions_deg(a, b)) > p.orthogonal_tol_deg:
                continue
            if sa + sb > best_score:
                best, best_score = (i, j), sa + sb
    top = max(range(len(cands)), key=lambda k: cands[k][1])
    if best is None or cands[top][1] > best_score:
        # Only one axis seen well: infer V2 ⟂ V1 on the horizon.
        a, sa = cands[top]
        inferred = np.cross(v3 / np.linalg.norm(v3), a)
        inferred /= np.linalg.norm(inferred)
        inferred = inferred if inferred[2] >= 0 else -inferred
        others = [c for k, c in enumerate(cands) if k != top]
        return ((a, sa), (inferred, 0.0), False), others
    i, j = best
    first, second = (i, j) if cands[i][1] >= cands[j][1] else (j, i)
    others = [c for k, c in enumerate(cands) if k not in best]
    return (cands[first], cands[second], True), others


def assign_segments(segments: np.ndarray, vps: np.ndarray, params: VPParams | None = None):
    """Label each segment with the layout VP it points at: V1, V2, V3 or NONE (−1).

    ``vps`` is K×3 homogeneous pixel points; a segment goes to the most consistent VP
    that passes both thresholds of :class:`VPParams` (angle and endpoint residual).
    Returns (labels int array (N,), angle_deg (N,) to the chosen VP).
    """
    p = params or VPParams()
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    if len(s) == 0:
        return np.empty(0, int), np.empty(0)
    angles, residuals = vp_consistency(s, np.asarray(vps, dtype=float).reshape(-1, 3))
    ok = (angles <= p.max_angle_deg) & (residuals <= p.residual_px)
    masked = np.where(ok, angles, np.inf)
    best = np.argmin(masked, axis=0)
    labels = np.where(np.isfinite(masked[best, np.arange(len(s))]), best, NONE)
    return labels.astype(int), angles[best, np.arange(len(s))]
