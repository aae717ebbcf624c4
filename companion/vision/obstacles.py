"""Non-Manhattan obstacles from pairs of corner projections (paper eqs. 5–8).

A pair ``G = {C_g, C_h}`` is typically the top and bottom corner of one vertical edge of
a rotated box standing on the floor. It is accepted when

- eq. 6, ``λ1 → 0``: the vertical legs ``L_r^g`` and ``L_r^h`` are collinear (λ1 here is
  the largest distance in pixels of one leg's endpoints from the other's line; 0 when
  both corners share one vertical segment);
- eq. 7, ``λ2 → π``: the vectors from each corner point to the midpoint of its vertical
  leg point in opposite directions (one corner above, one below);
- eq. 8, ``λ3 → 0``: the horizontal legs meet at obstacle VPs ``O1 = L_s^g × L_s^h`` and
  ``O2 = L_n^g × L_n^h`` (``O3`` = V3) that are consistent with a box on the floor: both
  on the horizon, at a right angle to each other, and away from the layout VPs V1, V2
  (else the corners are Manhattan after all). λ3 here is the larger of the horizon and
  the orthogonality error, in degrees.

Pairs that share their OVPs (within ``merge_deg``) are one obstacle, and further corners
whose legs pass through those OVPs join it (the paper's use of λ3 across corners).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.vision.corners import Corners
from companion.vision.geometry import (
    angle_between_directions_deg,
    direction_of,
    intersect,
    point_of,
    segment_lengths,
    segment_lines,
    segment_midpoints,
    vp_consistency,
)
from companion.vision.vanishing import V1, V2, V3, LayoutVPs

__all__ = ["ObstacleParams", "Obstacle", "find_obstacles"]


@dataclass(frozen=True)
class ObstacleParams:
    """Thresholds of eqs. 6–8 and of obstacle grouping."""

    collinear_px: float = 3.0  # λ1 gate (eq. 6)
    opposite_deg: float = 150.0  # λ2 gate: at least this angle (eq. 7)
    min_edge_px: float = 12.0  # corners of a pair at least this far apart
    horizon_tol_deg: float = 6.0  # λ3: OVP directions this close to horizontal (eq. 8)
    orthogonal_tol_deg: float = 20.0  # λ3: O1 ⟂ O2 within this (focal length is a guess)
    non_manhattan_min_deg: float = 5.0  # OVPs at least this far from V1 and V2
    merge_deg: float = 3.0  # pairs whose OVPs agree this well are one obstacle
    member_angle_deg: float = 3.0  # a further corner's legs point at the OVPs this well


@dataclass(frozen=True)
class Obstacle:
    """One non-Manhattan obstacle.

    ``ovps``: 3×3 unit homogeneous pixel points O1, O2, O3 (O3 = V3).
    ``corners_px``: K×2 corner projections that belong to it.
    ``pairs``: number of corner pairs (eqs. 5–8) supporting it.
    ``height_px``: longest vertical edge between paired corners (a size/nearness proxy).
    ``lambda3_deg``: the best pair's λ3 (eq. 8).
    """

    ovps: np.ndarray
    corners_px: np.ndarray
    pairs: int
    height_px: float
    lambda3_deg: float


def _collinearity_px(seg_a: np.ndarray, seg_b: np.ndarray) -> float:
    """λ1 (eq. 6): largest distance of either segment's endpoints from the other's line."""
    la, lb = segment_lines(np.vstack([seg_a, seg_b]))
    pa = np.array([[seg_a[0], seg_a[1], 1.0], [seg_a[2], seg_a[3], 1.0]])
    pb = np.array([[seg_b[0], seg_b[1], 1.0], [seg_b[2], seg_b[3], 1.0]])
    return float(max(np.abs(pb @ la).max(), np.abs(pa @ lb).max()))


def _opposite_deg(corner_g, mid_g, corner_h, mid_h) -> float:
    """λ2 (eq. 7): angle between the corner → vertical-leg-midpoint vectors, degrees."""
    a, b = mid_g - corner_g, mid_h - corner_h
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-9 or nb < 1e-9:
        return 0.0
    return float(np.degrees(np.arccos(np.clip(a @ b / (na * nb), -1.0, 1.0))))


def _ovp_error_deg(d1, d2, d3) -> float:
    """λ3 (eq. 8): how far O1, O2 are from horizontal, mutually orthogonal directions."""
    horizon = max(
        abs(90.0 - angle_between_directions_deg(d1, d3)),
        abs(90.0 - angle_between_directions_deg(d2, d3)),
    )
    ortho = abs(90.0 - angle_between_directions_deg(d1, d2))
    return float(horizon), float(ortho)


def find_obstacles(
    segments: np.ndarray,
    corners: Corners,
    layout: LayoutVPs,
    params: ObstacleParams | None = None,
) -> list[Obstacle]:
    """Obstacles from Table-I corners, largest (tallest vertical edge) first.

    Inputs: ``segments`` N×4 pixels; ``corners`` already filtered by Table I;
    ``layout`` the frame's layout VPs (V3 is O3; V1/V2 must differ from the OVPs).
    Output: a list of :class:`Obstacle`, possibly empty.
    """
    p = params or ObstacleParams()
    if len(corners) < 2:
        return []
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    lines = segment_lines(s)
    mids = segment_midpoints(s)
    f, c = layout.focal_px, layout.centre
    d3 = direction_of(layout.vps[V3], f, c)
    layout_dirs = direction_of(layout.vps[[V1, V2]], f, c)

    found: list[tuple[np.ndarray, np.ndarray, float, float, tuple[int, int]]] = []
    for g in range(len(corners)):
        for h in range(g + 1, len(corners)):
            pg, ph = corners.points_px[g], corners.points_px[h]
            edge = float(np.linalg.norm(pg - ph))
            if edge < p.min_edge_px:
                continue
            rg, rh = corners.r[g], corners.r[h]
            lam1 = 0.0 if rg == rh else _collinearity_px(s[rg], s[rh])
            if lam1 > p.collinear_px:
                continue
            if _opposite_deg(pg, mids[rg], ph, mids[rh]) < p.opposite_deg:
                continue
            best = None
            for a, b in (
                (corners.s[h], corners.n[h]),
                (corners.n[h], corners.s[h]),
            ):
                o1 = intersect(lines[corners.s[g]], lines[a])
                o2 = intersect(lines[corners.n[g]], lines[b])
                if not (np.any(o1) and np.any(o2)):
                    continue
                d1, d2 = direction_of(o1, f, c), direction_of(o2, f, c)
                horizon, ortho = _ovp_error_deg(d1, d2, d3)
                if horizon > p.horizon_tol_deg or ortho > p.orthogonal_tol_deg:
                    continue
                lam3 = max(horizon, ortho * p.horizon_tol_deg / p.orthogonal_tol_deg)
                if best is None or lam3 < best[2]:
                    best = (o1, o2, lam3)
            if best is None:
                continue
            o1, o2, lam3 = best
            d12 = direction_of(np.vstack([o1, o2]), f, c)
            sep = angle_between_directions_deg(d12[:, None, :], layout_dirs[None, :, :])
            if sep.min() < p.non_manhattan_min_deg:
                continue
            found.append((d12[0], d12[1], lam3, edge, (g, h)))

    if not found:
        return []
    groups = _group_by_ovps(found, p.merge_deg)
    obstacles = [_obstacle(members, found, s, corners, layout, p) for members in groups]
    obstacles.sort(key=lambda o: (-o.height_px, -o.pairs))
    return obstacles


def _group_by_ovps(found, merge_deg: float) -> list[list[int]]:
    """Union-find over pairs whose OVP sets agree within ``merge_deg``."""
    parent = list(range(len(found)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(len(found)):
        for j in range(i + 1, len(found)):
            a1, a2 = found[i][0], found[i][1]
            b1, b2 = found[j][0], found[j][1]
            same = min(
                max(angle_between_directions_deg(a1, b1), angle_between_directions_deg(a2, b2)),
                max(angle_between_directions_deg(a1, b2), angle_between_directions_deg(a2, b1)),
            )
            if same <= merge_deg:
                parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for i in range(len(found)):
        groups.setdefault(root(i), []).append(i)
    return list(groups.values())


def _obstacle(members, found, segments, corners: Corners, layout: LayoutVPs, p) -> Obstacle:
    """One obstacle from a group of pairs: OVPs refit on all legs, member corners joined."""
    f, c = layout.focal_px, layout.centre
    lines = segment_lines(segments)
    lengths = segment_lengths(segments)
    ref1, ref2 = found[members[0]][0], found[members[0]][1]
    paired = sorted({k for m in members for k in found[m][4]})
    # Refit each OVP on the horizontal legs of the paired corners that point at it.
    legs = np.unique(np.concatenate([corners.s[paired], corners.n[paired]]))
    fitted = []
    for ref in (ref1, ref2):
        ref_px = point_of(ref, f, c)
        angle, _ = vp_consistency(segments[legs], ref_px)
        mine = legs[angle <= max(p.member_angle_deg * 3, 6.0)]
        if len(mine) >= 2:
            w = lengths[mine]
            a = (lines[mine] * w[:, None]).T @ lines[mine]
            vp = np.linalg.eigh(a)[1][:, 0]
            fitted.append(vp if vp[2] >= 0 else -vp)
        else:
            fitted.append(ref_px)
    o1, o2 = fitted
    o3 = layout.vps[V3]
    # Further Table-I corners whose legs point at O1 and O2 join the obstacle (λ3).
    joined = list(paired)
    for k in range(len(corners)):
        if k in paired:
            continue
        a_s, _ = vp_consistency(segments[[corners.s[k]]], o1)
        a_n, _ = vp_consistency(segments[[corners.n[k]]], o2)
        b_s, _ = vp_consistency(segments[[corners.s[k]]], o2)
        b_n, _ = vp_consistency(segments[[corners.n[k]]], o1)
        if min(max(a_s[0], a_n[0]), max(b_s[0], b_n[0])) <= p.member_angle_deg:
            joined.append(k)
    return Obstacle(
        ovps=np.vstack([o1, o2, o3]),
        corners_px=corners.points_px[joined],
        pairs=len(members),
        height_px=max(found[m][3] for m in members),
        lambda3_deg=min(found[m][2] for m in members),
    )
