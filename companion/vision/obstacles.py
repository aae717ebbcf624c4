"""Non-Manhattan obstacles from pairs of corner projections (paper eqs. 5–8).

A pair ``G = {C_g, C_h}`` is typically the top and bottom corner of one vertical edge of
a rotated box standing on the floor. It is accepted when

- eq. 6, ``λ1 → 0``: the vertical legs ``L_r^g`` and ``L_r^h`` are collinear (λ1 here is
  the largest distance in pixels of one leg's endpoints from the other's line; 0 when
  both corners share one vertical segment);
- eq. 7, ``λ2 → π``: the vectors from each corner point to the midpoint of its vertical
  leg point in opposite directions (one corner above, one below); here by construction:
  ``C_h`` is searched only at the far end of ``C_g``'s vertical edge;
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
    endpoint_weights,
    horizon_line,
    intersect,
    point_of,
    segment_lengths,
    segment_lines,
    vp_consistency,
)
from companion.vision.vanishing import V1, V2, V3, LayoutVPs

__all__ = ["ObstacleParams", "Obstacle", "find_obstacles"]


@dataclass(frozen=True)
class ObstacleParams:
    """Thresholds of eqs. 6–8 and of obstacle grouping."""

    collinear_px: float = 3.0  # λ1 gate (eq. 6)
    min_edge_px: float = 12.0  # corners of a pair at least this far apart
    horizon_tol_deg: float = 6.0  # λ3: OVP directions this close to horizontal (eq. 8)
    orthogonal_tol_deg: float = 20.0  # λ3: O1 ⟂ O2 within this (focal length is a guess)
    single_corner_orthogonal_tol_deg: float = 8.0  # the same when C_h shows no leg
    non_manhattan_min_deg: float = 5.0  # OVPs at least this far from V1 and V2
    merge_deg: float = 3.0  # pairs whose OVPs agree this well are one obstacle
    member_angle_deg: float = 3.0  # a further corner's legs point at the OVPs this well
    refit_slack_deg: float = 2.0  # an OVP refit at most this farther from horizontal/orthogonal


@dataclass(frozen=True)
class Obstacle:
    """One non-Manhattan obstacle.

    ``ovps``: 3×3 unit homogeneous pixel points O1, O2, O3 (O3 = V3).
    ``corners_px``: K×2 corner projections that belong to it.
    ``pairs``: number of Table-I corners whose vertical edge led to a consistent partner
    (a full pair, a partner with one leg, or no visible partner leg) supporting it.
    ``height_px``: longest vertical edge between paired corners (a size/nearness proxy).
    ``lambda3_deg``: the best pair's λ3 (eq. 8).
    """

    ovps: np.ndarray
    corners_px: np.ndarray
    pairs: int
    height_px: float
    lambda3_deg: float


def _horizon_error_deg(d, d3):
    """How far OVP direction(s) ``d`` (…×3) are from horizontal (⟂ the vertical V3), degrees."""
    return np.abs(90.0 - angle_between_directions_deg(d, d3))


def _ovp_error_deg(d1, d2, d3):
    """λ3 (eq. 8) parts: how far O1, O2 are from horizontal, and from orthogonal
    (directions …×3, so many candidate pairs are checked at once)."""
    horizon = np.maximum(_horizon_error_deg(d1, d3), _horizon_error_deg(d2, d3))
    ortho = np.abs(90.0 - angle_between_directions_deg(d1, d2))
    return horizon, ortho


def _far_ends(corners: Corners, segments, lines, verticals, p: ObstacleParams):
    """The other end of each corner's vertical edge, following collinear V3 segments.

    A V3 segment is on the edge of ``L_r^g`` when λ1 (eq. 6), the largest distance of
    either segment's endpoints from the other's line, is within ``collinear_px``. The
    far end is the endpoint farthest from ``p_c`` on the side of the leg's midpoint
    (λ2 → π, eq. 7: the partner lies the other way from its own leg).
    Returns (far ends K×2, edge lengths K, usable K bool): all corners at once.
    """
    pc = corners.points_px
    rg = segments[corners.r]
    u = 0.5 * (rg[:, :2] + rg[:, 2:]) - pc
    norm = np.hypot(u[:, 0], u[:, 1])
    ok = norm >= 1e-9
    u = u / np.where(ok, norm, 1.0)[:, None]
    vends = segments[verticals].reshape(-1, 2, 2)[None]  # 1×V×2×2
    rl, vl = lines[corners.r][:, None, None, :], lines[verticals][None, :, None, :]
    rends = rg.reshape(-1, 2, 2)[:, None]  # K×1×2×2
    lam1 = np.maximum(
        np.abs(vends[..., 0] * rl[..., 0] + vends[..., 1] * rl[..., 1] + rl[..., 2]).max(axis=2),
        np.abs(rends[..., 0] * vl[..., 0] + rends[..., 1] * vl[..., 1] + vl[..., 2]).max(axis=2),
    )
    on_edge = (verticals[None] == corners.r[:, None]) | (lam1 <= p.collinear_px)
    along = ((vends[..., 0] - pc[:, None, None, 0]) * u[:, None, None, 0]
             + (vends[..., 1] - pc[:, None, None, 1]) * u[:, None, None, 1]).max(axis=2)
    reach = np.where(on_edge, along, -np.inf).max(axis=1, initial=-np.inf)
    ok &= reach >= p.min_edge_px
    return pc + np.where(ok, reach, 0.0)[:, None] * u, reach, ok


def _partner_legs(corners: Corners, g, far, edge, free_idx, lines, ends, radius_px,
                  leg_gap_frac) -> np.ndarray:
    """Which free segments are legs of C_h at the far end of each corner ``g``'s edge.

    A leg's line must cross the vertical line within ``radius_px + leg_gap_frac · edge``
    of the far end, on the far half of the edge from ``p_c``, and the leg must end within
    ``radius_px`` of that crossing; C_g's own legs are not C_h's. Returns G×F bool over
    ``free_idx``.
    """
    pc, e = corners.points_px[g], far
    vline = np.column_stack([pc[:, 1] - e[:, 1], e[:, 0] - pc[:, 0],
                             pc[:, 0] * e[:, 1] - pc[:, 1] * e[:, 0]])
    vline /= np.hypot(vline[:, 0], vline[:, 1])[:, None]
    q_h = intersect(lines[free_idx][None], vline[:, None])
    w = q_h[..., 2]
    ok = np.abs(w) >= 1e-12
    q = q_h[..., :2] / np.where(ok, w, 1.0)[..., None]
    axis = (e - pc) / edge[:, None]
    ok &= (np.hypot(q[..., 0] - e[:, None, 0], q[..., 1] - e[:, None, 1])
           <= (radius_px + leg_gap_frac * edge)[:, None])
    ok &= ((q[..., 0] - pc[:, None, 0]) * axis[:, None, 0]
           + (q[..., 1] - pc[:, None, 1]) * axis[:, None, 1]) >= 0.5 * edge[:, None]
    fe = ends[free_idx][None]  # 1×F×2×2
    end_gap = np.minimum(np.hypot(fe[..., 0, 0] - q[..., 0], fe[..., 0, 1] - q[..., 1]),
                         np.hypot(fe[..., 1, 0] - q[..., 0], fe[..., 1, 1] - q[..., 1]))
    ok &= end_gap <= radius_px
    ok &= (free_idx[None] != corners.s[g][:, None]) & (free_idx[None] != corners.n[g][:, None])
    return ok


def _off_layout(dirs, layout_dirs, p: ObstacleParams) -> np.ndarray:
    """For each OVP direction in ``dirs`` (…×3): at least ``non_manhattan_min_deg`` from
    V1 and V2 (``layout_dirs`` 2×3)."""
    sep = angle_between_directions_deg(np.asarray(dirs)[..., None, :], layout_dirs)
    return sep.min(axis=-1) >= p.non_manhattan_min_deg


def _horizon_ovps(leg_a, leg_b, lines, horizon, d3, layout_dirs, f, c, p: ObstacleParams):
    """OVPs where two legs (index arrays) cross the horizon, for pairs whose other ends
    show no leg: then the horizon test holds by construction, so only the tight
    ``single_corner_orthogonal_tol_deg`` and the distance from V1, V2 separate a box
    from chance. Returns (d1, d2, orthogonality error in degrees, passes)."""
    o1, o2 = intersect(lines[leg_a], horizon), intersect(lines[leg_b], horizon)
    d1, d2 = direction_of(o1, f, c), direction_of(o2, f, c)
    _, ortho = _ovp_error_deg(d1, d2, d3)
    ok = (np.any(o1, axis=1) & np.any(o2, axis=1)
          & (ortho <= p.single_corner_orthogonal_tol_deg)
          & _off_layout(d1, layout_dirs, p) & _off_layout(d2, layout_dirs, p))
    return d1, d2, ortho, ok


def _partner_ovps(legs, partners, lines, horizon, d3, layout_dirs, f, c, p: ObstacleParams):
    """The best OVPs of each corner C_g's legs paired with the legs of its partner C_h.

    ``legs`` G×2 (L_s, L_n of each C_g); ``partners`` G lists of C_h's legs. Every
    combination of every corner at once: O1 = one leg of C_g × a partner leg ``h``; O2 =
    the other leg × a second partner leg ``h2``, or × the horizon when C_h shows only one
    leg. Two real partner legs beat one; then the smaller λ3 (eq. 8), first found on ties.
    Returns {corner row: (d1, d2, λ3)} for the corners with a consistent partner.
    """
    combos = [(gi, h, a, h2) for gi, hs in enumerate(partners) for h in hs for a in (0, 1)
              for h2 in (-1, *hs) if h2 != h]
    if not combos:
        return {}
    gi, h, a, h2 = np.array(combos).T
    o1 = intersect(lines[legs[gi, a]], lines[h])
    o2 = intersect(lines[legs[gi, 1 - a]], np.where((h2 < 0)[:, None], horizon, lines[h2]))
    d1, d2 = direction_of(o1, f, c), direction_of(o2, f, c)
    hor, ortho = _ovp_error_deg(d1, d2, d3)
    ok = (np.any(o1, axis=1) & np.any(o2, axis=1) & (hor <= p.horizon_tol_deg)
          & (ortho <= p.orthogonal_tol_deg) & _off_layout(d1, layout_dirs, p)
          & _off_layout(d2, layout_dirs, p))
    lam3 = np.maximum(hor, ortho * p.horizon_tol_deg / p.orthogonal_tol_deg)
    rows = np.flatnonzero(ok)
    rows = rows[np.lexsort((rows, lam3[rows], h2[rows] < 0, gi[rows]))]
    _, first = np.unique(gi[rows], return_index=True)
    return {int(gi[k]): (d1[k], d2[k], float(lam3[k])) for k in rows[first]}


def find_obstacles(
    segments: np.ndarray,
    corners: Corners,
    layout: LayoutVPs,
    free: np.ndarray,
    labels: np.ndarray,
    params: ObstacleParams | None = None,
    radius_px: float = 10.0,
    leg_gap_frac: float = 0.15,
) -> list[Obstacle]:
    """Obstacles from Table-I corners, best supported first: most consistent corner pairs
    (hypotheses of one box from a stray pair are common, from many pairs rare), then the
    tallest vertical edge (the nearest or largest box).

    For each Table-I corner ``C_g`` the vertical edge is followed to its other end
    (eqs. 6, 7) and the non-Manhattan legs ending there form ``C_h``. With two legs this
    is the paper's pair; a leg of ``C_h`` that the line detector missed (a thin top face,
    low contrast against the wall) is replaced by the horizon: ``O = L^g ∩ horizon``.
    At least one OVP must come from two real edges (``L^g × L^h``), and λ3 (eq. 8) holds.

    Inputs: ``segments`` N×4 pixels; ``corners`` already filtered by Table I;
    ``layout`` the frame's layout VPs; ``free`` N bool, segments that may be obstacle
    legs (not V3, not tightly V1/V2); ``labels`` N segment labels (V3 = vertical).
    Output: a list of :class:`Obstacle`, possibly empty.
    """
    p = params or ObstacleParams()
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    if len(s) == 0:
        return []
    lines = segment_lines(s)
    f, c = layout.focal_px, layout.centre
    d3 = direction_of(layout.vps[V3], f, c)
    horizon = horizon_line(layout.vps[V3], f, c)
    layout_dirs = direction_of(layout.vps[[V1, V2]], f, c)
    verticals = np.flatnonzero(np.asarray(labels) == V3)
    free_idx = np.flatnonzero(free)
    ends = s.reshape(-1, 2, 2)

    # (d1, d2, λ3, edge length, corner indices, extra leg segments, extra corner points)
    found: list[tuple] = []
    if len(corners) and len(verticals):
        far, edge, usable = _far_ends(corners, s, lines, verticals, p)
        g = np.flatnonzero(usable)
        is_leg = _partner_legs(corners, g, far[g], edge[g], free_idx, lines, ends, radius_px,
                               leg_gap_frac)
        legs = np.column_stack([corners.s[g], corners.n[g]])
        best = _partner_ovps(legs, [free_idx[row] for row in is_leg], lines, horizon, d3,
                             layout_dirs, f, c, p)
        # C_h has no visible leg at all: both OVPs from C_g's legs on the horizon.
        alone = np.array([k for k in range(len(g)) if k not in best
                          and edge[g[k]] >= 2 * p.min_edge_px], dtype=int)
        d1, d2, ortho, lone_ok = _horizon_ovps(legs[alone, 0], legs[alone, 1], lines, horizon,
                                               d3, layout_dirs, f, c, p)
        for k in np.flatnonzero(lone_ok):
            best[int(alone[k])] = (d1[k], d2[k], float(ortho[k]))
        for k in sorted(best):
            d1k, d2k, lam3 = best[k]
            found.append((d1k, d2k, lam3, float(edge[g[k]]), (int(g[k]),), (), np.empty((0, 2))))

    # Vertical edges whose ends show only two-leg corners (outline edges, low contrast).
    edges = _edge_legs(s, verticals, free_idx, ends, p, radius_px, leg_gap_frac)
    found += _pair_halves(_silhouette_halves(edges, lines, d3, layout_dirs, f, c, p), d3, p)
    if not found:
        found += _edge_horizon_pairs(edges, lines, horizon, d3, layout_dirs, f, c, p)
    if not found:
        return []
    groups = _group_by_ovps(found, p.merge_deg)
    obstacles = [_obstacle(members, found, s, corners, layout, p) for members in groups]
    obstacles.sort(key=lambda o: (-o.pairs, -o.height_px))  # the first one drives η
    return obstacles


def _group_by_ovps(found, merge_deg: float) -> list[list[int]]:
    """Union-find over pairs whose OVP sets agree within ``merge_deg``."""
    parent = list(range(len(found)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    if len(found) > 1:
        a1, a2 = np.array([x[0] for x in found]), np.array([x[1] for x in found])
        i, j = np.triu_indices(len(found), k=1)
        same = np.minimum(
            np.maximum(angle_between_directions_deg(a1[i], a1[j]),
                       angle_between_directions_deg(a2[i], a2[j])),
            np.maximum(angle_between_directions_deg(a1[i], a2[j]),
                       angle_between_directions_deg(a2[i], a1[j])),
        )
        for k in np.flatnonzero(same <= merge_deg):
            parent[root(int(i[k]))] = root(int(j[k]))
    groups: dict[int, list[int]] = {}
    for i in range(len(found)):
        groups.setdefault(root(i), []).append(i)
    return list(groups.values())


def _obstacle(members, found, segments, corners: Corners, layout: LayoutVPs, p) -> Obstacle:
    """One obstacle from a group of pairs: OVPs refit on all legs, member corners joined."""
    f, c = layout.focal_px, layout.centre
    lines = segment_lines(segments)
    ref1, ref2 = found[members[0]][0], found[members[0]][1]
    paired = sorted({k for m in members for k in found[m][4]})
    extra_legs = [k for m in members for k in found[m][5]]
    extra_points = np.vstack([found[m][6] for m in members] + [np.empty((0, 2))])
    # Refit each OVP on the horizontal legs of the paired corners that point at it.
    legs = np.unique(np.concatenate([corners.s[paired], corners.n[paired], extra_legs])
                     ).astype(int)
    fitted = []
    for ref in (ref1, ref2):
        ref_px = point_of(ref, f, c)
        angle, _ = vp_consistency(segments[legs], ref_px)
        mine = legs[angle <= max(p.member_angle_deg * 3, 6.0)]
        if len(mine) >= 2:
            # Least squares on endpoint residuals, as for the layout VPs.
            vp = ref_px
            for _ in range(2):
                w = endpoint_weights(segments[mine], vp)
                vp = np.linalg.eigh((lines[mine] * w[:, None]).T @ lines[mine])[1][:, 0]
            fitted.append(vp if vp[2] >= 0 else -vp)
        else:
            fitted.append(ref_px)
    o1, o2 = fitted
    o3 = layout.vps[V3]
    # Legs that are nearly parallel in the image fix their OVP poorly: a refit that breaks
    # the box model (λ3, eq. 8) is noise, not a better estimate, so keep the pair's OVPs.
    d3 = direction_of(o3, f, c)
    fit = _ovp_error_deg(direction_of(o1, f, c), direction_of(o2, f, c), d3)
    ref = _ovp_error_deg(ref1, ref2, d3)
    if any(a > b + p.refit_slack_deg for a, b in zip(fit, ref, strict=True)):
        o1, o2 = point_of(ref1, f, c), point_of(ref2, f, c)
    # Further Table-I corners whose legs point at O1 and O2 join the obstacle (λ3).
    joined = list(paired)
    if paired:
        angles = [vp_consistency(segments[legs_k], o)[0]
                  for legs_k in (corners.s, corners.n) for o in (o1, o2)]
        a_s, b_s, b_n, a_n = angles  # s→O1, s→O2, n→O1, n→O2
        fits = np.minimum(np.maximum(a_s, a_n), np.maximum(b_s, b_n)) <= p.member_angle_deg
        fits[paired] = False
        joined += np.flatnonzero(fits).tolist()
    return Obstacle(
        ovps=np.vstack([o1, o2, o3]),
        corners_px=_unique_points(np.vstack([corners.points_px[joined], extra_points])),
        pairs=len(members),
        height_px=max(found[m][3] for m in members),
        lambda3_deg=min(found[m][2] for m in members),
    )


def _unique_points(points: np.ndarray, tol_px: float = 3.0) -> np.ndarray:
    keep: list[np.ndarray] = []
    for q in points:
        if all(np.linalg.norm(q - k) > tol_px for k in keep):
            keep.append(q)
    return np.array(keep).reshape(-1, 2)


def _vertical_chains(s, verticals, p: ObstacleParams, radius_px, leg_gap_frac):
    """Vertical edges: V3 segments joined with collinear ones (λ1, eq. 6) across small gaps.

    Returns a list of (end_a, end_b, length) with the two extreme endpoints.
    """
    chains = []
    if len(verticals) == 0:
        return chains
    lines = segment_lines(s[verticals])
    lengths = segment_lengths(s[verticals])
    pts_h = np.concatenate([s[verticals].reshape(-1, 2, 2), np.ones((len(verticals), 2, 1))], 2)
    # Distance of the shorter segment's endpoints from the longer one's line: a short
    # piece's own direction is too noisy to extrapolate along a long edge.
    dist = np.abs(np.einsum("ik,jek->ije", lines, pts_h)).max(axis=2)
    shorter_from_longer = np.where(lengths[:, None] >= lengths[None, :], dist, dist.T)
    collinear = shorter_from_longer <= p.collinear_px
    np.fill_diagonal(collinear, True)
    # One chain per distinct set of collinear members, grown from its first segment.
    singles = collinear.sum(axis=1) == 1
    seen: set[bytes] = set()
    for iv in range(len(verticals)):
        if singles[iv]:  # most vertical segments: the chain is the segment itself
            if lengths[iv] >= 2 * p.min_edge_px:
                v = verticals[iv]
                chains.append((s[v, :2].copy(), s[v, 2:].copy(), float(lengths[iv])))
            continue
        members_key = collinear[iv].tobytes()
        if members_key in seen:
            continue
        seen.add(members_key)
        others = np.flatnonzero(collinear[iv])
        local = np.concatenate([[iv], others[others != iv]])
        members = verticals[local]
        # Measure along the longest member: its direction is the most accurate.
        base = members[int(np.argmax(lengths[local]))]
        origin = s[base, :2]
        axis = s[base, 2:] - origin
        axis /= max(np.linalg.norm(axis), 1e-9)
        pts = s[members].reshape(-1, 2)
        t = (pts - origin) @ axis
        # Grow from segment v along the axis while the gaps stay small.
        spans = sorted((min(t[2 * i], t[2 * i + 1]), max(t[2 * i], t[2 * i + 1]))
                        for i in range(len(members)))
        lo, hi = min(t[0], t[1]), max(t[0], t[1])  # segment v itself
        for a, b in spans + spans[::-1]:
            gap = radius_px + leg_gap_frac * (hi - lo)
            if a <= hi + gap and b >= lo - gap:
                lo, hi = min(lo, a), max(hi, b)
        if hi - lo >= 2 * p.min_edge_px:
            chains.append((origin + lo * axis, origin + hi * axis, hi - lo))
    return chains


def _edge_legs(s, verticals, free_idx, ends, p: ObstacleParams, radius_px, leg_gap_frac):
    """Vertical edges with the non-Manhattan legs that end at each of their two ends.

    Returns a list of (end_a, end_b, length, legs_a, legs_b); a leg is (segment index,
    side): the side (±1) of the edge it leaves toward. Legs are at least 20° off the edge.
    """
    out = []
    chains = _vertical_chains(s, verticals, p, radius_px, leg_gap_frac)
    if len(free_idx) == 0 or not chains:
        return out
    # Every chain end against every free segment's two ends at once (2C × F × 2).
    chain_ends = np.array([[a, b] for a, b, _ in chains]).reshape(-1, 2)
    free_ends = ends[free_idx]
    diff = free_ends[None] - chain_ends[:, None, None, :]
    dist2 = np.einsum("cfek,cfek->cfe", diff, diff)
    near_end = np.argmin(dist2, axis=2)  # which end of the leg is at the chain end
    near = dist2.min(axis=2) <= radius_px ** 2
    # Each leg leaves its chain end along ``away`` (its far end minus its near end); it
    # counts when it is long enough and at least 20° off the edge, on either side.
    span = free_ends[:, 1] - free_ends[:, 0]
    leg_len = np.hypot(span[:, 0], span[:, 1])
    axes = np.array([(b - a) / length for a, b, length in chains]).repeat(2, axis=0)
    side = np.where(near_end == 0, 1.0, -1.0) * (
        axes[:, 0, None] * span[None, :, 1] - axes[:, 1, None] * span[None, :, 0]
    ) / np.maximum(leg_len, 1e-12)[None]
    keep = near & (leg_len >= p.min_edge_px)[None] & (np.abs(side) >= np.sin(np.radians(20.0)))
    legs: list[list] = [[] for _ in range(len(axes))]
    for e, k in zip(*np.nonzero(keep), strict=True):
        legs[e].append((int(free_idx[k]), np.sign(side[e, k])))
    for c, (end_a, end_b, length) in enumerate(chains):
        if legs[2 * c] or legs[2 * c + 1]:
            out.append((end_a, end_b, length, legs[2 * c], legs[2 * c + 1]))
    return out


def _silhouette_halves(edges, lines, d3, layout_dirs, f, c, p: ObstacleParams):
    """One OVP from each vertical edge whose two ends both show a leg on the same side.

    A box's outline edge (and any vertical edge with one face hidden) gives corners of
    two legs only: the vertical edge and one horizontal edge at each end. When the two
    horizontal edges bound one face they are parallel in space and meet at that face's
    OVP (eqs. 6–8 with one leg per corner), which must lie on the horizon and away from
    V1 and V2. Returns a list of (direction, edge length, legs, corner points).
    """
    combos = [(e, ka, kb) for e, (_, _, _, legs_a, legs_b) in enumerate(edges)
              for ka, sa in legs_a for kb, sb in legs_b if sa == sb]
    if not combos:
        return []
    e, ka, kb = np.array(combos).T
    o = intersect(lines[ka], lines[kb])
    d = direction_of(o, f, c)
    ok = (np.any(o, axis=1) & (_horizon_error_deg(d, d3) <= p.horizon_tol_deg)
          & _off_layout(d, layout_dirs, p))
    return [(d[k], edges[e[k]][2], (int(ka[k]), int(kb[k])),
             np.vstack([edges[e[k]][0], edges[e[k]][1]])) for k in np.flatnonzero(ok)]


def _edge_horizon_pairs(edges, lines, horizon, d3, layout_dirs, f, c, p: ObstacleParams):
    """A leg at each end of one vertical edge whose horizon crossings are orthogonal OVPs.

    The fallback for an edge whose two legs bound two different faces (a box seen from
    above its top, its faces too alike for the edge between them to show): each leg's OVP
    is where it crosses the horizon, and only the tight ``single_corner_orthogonal_tol_deg``
    separates a box from chance, as for a single corner. One leg must be at each end:
    two legs at one end may be a rug's corner touching a door frame.
    """
    combos = [(e, ka, kb) for e, (_, _, length, legs_a, legs_b) in enumerate(edges)
              if length >= 2 * p.min_edge_px for ka, _ in legs_a for kb, _ in legs_b if ka != kb]
    if not combos:
        return []
    e, ka, kb = np.array(combos).T
    da, db, ortho, ok = _horizon_ovps(ka, kb, lines, horizon, d3, layout_dirs, f, c, p)
    found = []
    for edge in np.unique(e[ok]):  # per edge, its most orthogonal pair (first on ties)
        idx = np.flatnonzero(ok & (e == edge))
        k = idx[np.argmin(ortho[idx])]
        end_a, end_b, length, _, _ = edges[edge]
        found.append((da[k], db[k], float(ortho[k]), length, (), (int(ka[k]), int(kb[k])),
                      np.vstack([end_a, end_b])))
    return found


def _pair_halves(halves, d3, p: ObstacleParams) -> list[tuple]:
    """Two silhouette OVPs at a right angle (λ3, eq. 8) make an obstacle hypothesis."""
    if len(halves) < 2:
        return []
    dirs = np.array([h[0] for h in halves])
    i, j = np.triu_indices(len(halves), k=1)
    hor, ortho = _ovp_error_deg(dirs[i], dirs[j], d3)
    lam3 = np.maximum(hor, ortho * p.horizon_tol_deg / p.orthogonal_tol_deg)
    found = []
    for k in np.flatnonzero(ortho <= p.orthogonal_tol_deg):
        (d1, len1, legs1, pts1), (d2, len2, legs2, pts2) = halves[i[k]], halves[j[k]]
        found.append((d1, d2, float(lam3[k]), max(len1, len2), (), legs1 + legs2,
                      np.vstack([pts1, pts2])))
    return found
