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
whose legs pass through those OVPs join it (the paper's use of λ3 across corners). Its
OVPs are then fitted to all its horizontal edges at once as one box's yaw about the
vertical (:func:`fit_box_ovps`): eq. 8 with λ3 = 0, given the focal length.
An obstacle that would show a face edge-on at every one of its corners is dropped
(:func:`edge_on_angle_deg`): its vertical edge is more likely a line on the floor aimed at
the camera's foot, and the rules that run when nothing is found then run. For the same
reason a hidden-edge corner (two legs meeting where no vertical edge shows) counts only
where neither leg is seen edge-on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from companion.vision._obstacles import RULES, find
from companion.vision._obstacles import edge_on_angle as _edge_on_angle
from companion.vision._obstacles import fit_box_ovps as _fit_box_ovps
from companion.vision.corners import Corners
from companion.vision.vanishing import V1, V2, V3, LayoutVPs

__all__ = ["ObstacleParams", "Obstacle", "RULES", "edge_on_angle_deg", "find_obstacles",
           "fit_box_ovps"]


@dataclass(frozen=True)
class ObstacleParams:
    """Thresholds of eqs. 6–8 and of obstacle grouping."""

    collinear_px: float = 3.0  # λ1 gate (eq. 6)
    min_edge_px: float = 12.0  # corners of a pair at least this far apart
    horizon_tol_deg: float = 6.0  # λ3: OVP directions this close to horizontal (eq. 8)
    orthogonal_tol_deg: float = field(default=20.0, metadata={"range": (0.1, 45.0)})
    """λ3: O1 ⟂ O2 within this (focal length is a guess); a divisor of λ3"""
    single_corner_orthogonal_tol_deg: float = 8.0  # the same when C_h shows no leg
    single_corner_noise_deg: float = field(default=16.0, metadata={"range": (0.1, 180.0)})
    """... and that test counts only where ``noise_px`` across the legs' ends (each end
    alone, root sum of squares) moves the right angle by at most this: else noise alone
    decides it (short legs, or one nearly along the horizon, as an aligned table's or a
    shadow's), and chance passes it as readily as a box does"""
    single_face_tol_deg: float = 3.0  # when one face is all there is of a box: its OVP this
    # close to horizontal, and the room's V1 ⟂ V2 this close (its other OVP is at a right
    # angle through the focal length); a face seen from below its top, or by its foot:
    # ``noise_px`` at that edge's ends moves its OVP by at most this
    settled_focal_tol_deg: float = 6.0
    """... the room's V1 ⟂ V2 this close instead when the focal length is a video's settled
    running estimate (``focal_settled``): the median of many frames' estimates, so the
    frame's departure from a right angle is its VPs' noise more than a wrong focal length
    (a settled frame's VPs are fitted with no orthogonality prior, which would bias the
    frame's own vote for the focal length)"""
    non_manhattan_min_deg: float = 5.0  # OVPs at least this far from V1 and V2
    merge_deg: float = 3.0  # pairs whose OVPs agree this well are one obstacle
    member_angle_deg: float = 3.0  # a further corner's legs point at the OVPs this well (and a
    # face's outline edges at V3)
    refit_slack_deg: float = 2.0  # an OVP refit at most this farther from horizontal/orthogonal
    box_fit: bool = True  # OVPs fitted as one box's yaw about V3 (fit_box_ovps)
    hidden_edge_corners: bool = True  # two legs meeting where no vertical edge shows, one
    # running on to a vertical edge: a box corner whose faces are lit alike
    edge_on_deg: float = field(default=3.0, metadata={"range": (0.0, 45.0)})
    """an obstacle each of whose corners lies within this of an OVP's bearing would show a
    face edge-on at every corner, as a line on the floor aimed at the camera's foot does
    (:func:`edge_on_angle_deg`), and a hidden-edge corner so near one of its legs' bearings
    has that leg where its unseen vertical edge would be; 0 keeps every obstacle"""


@dataclass(frozen=True)
class Obstacle:
    """One non-Manhattan obstacle.

    ``ovps``: 3×3 unit homogeneous pixel points O1, O2, O3 (O3 = V3).
    ``corners_px``: K×2 corner projections that belong to it.
    ``pairs``: number of Table-I corners whose vertical edge led to a consistent partner
    (a full pair, a partner with one leg, or no visible partner leg) supporting it.
    ``height_px``: longest vertical edge between paired corners (a size/nearness proxy).
    ``lambda3_deg``: the best pair's λ3 (eq. 8).
    ``rule``: which rule of :func:`find_obstacles` read it (one of :data:`RULES`), for
    diagnosis: ``corner pair`` is the paper's eqs. 5–8, the others read boxes that show
    fewer corners.
    """

    ovps: np.ndarray
    corners_px: np.ndarray
    pairs: int
    height_px: float
    lambda3_deg: float
    rule: str = "corner pair"


def find_obstacles(
    segments: np.ndarray,
    corners: Corners,
    layout: LayoutVPs,
    free: np.ndarray,
    labels: np.ndarray,
    params: ObstacleParams | None = None,
    radius_px: float = 10.0,
    leg_gap_frac: float = 0.15,
    min_leg_angle_deg: float = 12.0,
    noise_px: float = 1.0,
    focal_settled: bool = False,
) -> list[Obstacle]:
    """Obstacles from Table-I corners, best supported first: most consistent corner pairs
    (hypotheses of one box from a stray pair are common, from many pairs rare), then the
    tallest vertical edge (the nearest or largest box).

    For each Table-I corner ``C_g`` the vertical edge is followed to its other end
    (eqs. 6, 7) and the non-Manhattan legs ending there form ``C_h``. With two legs this
    is the paper's pair; a leg of ``C_h`` that the line detector missed (a thin top face,
    low contrast against the wall) is replaced by the horizon: ``O = L^g ∩ horizon``.
    At least one OVP must come from two real edges (``L^g × L^h``), and λ3 (eq. 8) holds.
    With no leg of ``C_h`` at all, both OVPs are where ``C_g``'s legs cross the horizon
    (at a right angle that the legs' pixel noise alone could not make or break:
    ``single_corner_noise_deg``; the same for the later rules that take OVPs there),
    unless a room edge leaves the vertical edge's far end inside the frame (a door frame or
    an aligned box, with a rug's or a shadow's corner at its foot), or, with ``C_g`` at
    the edge's foot, its near end where that stops more than ``radius_px`` above ``C_g``
    (the edge stands on the room's floor line there, not on ``C_g``; under a table's top
    the room shows between the legs, so a top corner is not tested). A ``C_g`` at the
    edge's foot must have its legs on either side of the edge, as the bottom edges of a
    convex box's two faces in sight are; two on one side are a rug's or a shadow's.
    When no pair is found this way, boxes that show fewer corners are looked for, by
    every one of these rules at once, their hypotheses grouped together: leg junctions one
    above the other; vertical edges with a leg at each end (at an end where
    a room edge comes nearer than the leg, by more than ``noise_px``, on the leg's side,
    the end is a door frame's corner and the leg not the edge's); (with
    ``hidden_edge_corners``) two legs meeting where no vertical edge shows, neither seen
    edge-on there (``edge_on_deg``), on either side of the unseen edge, one of them
    running on to a vertical edge at its far end; a box showing one face; and last a
    face's top edge with vertical edges hanging from it (a table seen from the front, its
    legs under the top; the outermost two spanning half the top or more). Taking the
    first rule that found anything instead let a weaker rule's wrong reading (a face of
    an aligned box bent by the lens, a table read on the wrong legs) hide another rule's
    reading of the obstacle. An obstacle edge-on at every corner (:func:`edge_on_angle_deg`
    below ``edge_on_deg``) is dropped; when the pairs' obstacles are all dropped, the
    other rules run as if none had been found.

    Each obstacle names the rule that read it (``Obstacle.rule``, for diagnosis; the
    group's first hypothesis's when several read one box): ``corner pair`` (eqs. 5–8, a
    missed leg of ``C_h`` replaced by the horizon), ``single corner`` (no leg of ``C_h``),
    ``leg junctions``, ``two faces`` (two vertical edges whose end legs meet on the
    horizon, at a right angle), ``edge legs`` (a leg at each end of one vertical edge),
    ``hidden edge``, ``one face``, ``hanging face``, ``standing face``.

    Inputs: ``segments`` N×4 pixels; ``corners`` already filtered by Table I;
    ``layout`` the frame's layout VPs; ``free`` N bool, segments that may be obstacle
    legs (not V3, not tightly V1/V2); ``labels`` N segment labels (V3 = vertical);
    ``noise_px`` how far two segment ends may be apart and not be told nearer or farther;
    ``focal_settled`` whether ``layout.focal_px`` is a video's settled running estimate.
    Output: a list of :class:`Obstacle`, possibly empty.
    """
    p = params or ObstacleParams()
    found = find(segments, corners.points_px, corners.s, corners.n, corners.r, layout.vps,
                 layout.focal_px, layout.centre[0], layout.centre[1], free, labels, V3, p,
                 radius_px, leg_gap_frac, math.sin(math.radians(min_leg_angle_deg)),
                 layout.observed[V1] and layout.observed[V2], noise_px, focal_settled)
    obstacles = [Obstacle(*fields) for fields in found]
    obstacles.sort(key=lambda o: (-o.pairs, -o.height_px))  # the first one drives η
    return obstacles


def edge_on_angle_deg(obstacle: Obstacle, layout: LayoutVPs) -> float:
    """How nearly edge-on the obstacle shows a face at each of its corners: the largest,
    over its corners, of the angle in the horizontal plane between the ray to the corner
    and the nearer of its two OVPs.

    At a corner where that angle is 0 the camera lies in the plane of the face that runs
    along that OVP through the corner: the face shows nothing, and its edges lie on the
    corner's own line through V3. A line on the floor (or the ceiling) aimed at the point
    below the camera is such a line too: it lies in a vertical plane through the camera,
    so its image passes through V3 as a vertical edge's does, and its direction is its
    bearing. A rug's or a shadow's side is taken for a box's vertical edge this way, the
    rug's other sides for legs, and the side itself gives the other OVP. A real box seen
    with one face edge-on still shows another vertical edge where no face is edge-on; an
    obstacle that is edge-on at every corner cannot be told from the rug. (Edge-on at any
    one corner would also drop a box whose face the vehicle flies along, in that face's
    plane: a course onto its edge.)

    Inputs: an :class:`Obstacle`; the frame's ``layout`` (V3, focal length, centre).
    Output: degrees in [0, 90]; 90 for an obstacle without corners.
    """
    return _edge_on_angle(obstacle.corners_px, obstacle.ovps, layout.vps, layout.focal_px,
                          layout.centre[0], layout.centre[1])


def fit_box_ovps(legs: np.ndarray, ovps: np.ndarray, layout: LayoutVPs,
                 max_angle_deg: float = 9.0) -> np.ndarray | None:
    """O1 and O2 of one box standing on the floor, fitted to all its horizontal edges.

    A box's horizontal edges run along two directions that are horizontal (⟂ V3) and at a
    right angle to each other (eq. 8 with λ3 = 0), so given the focal length the two OVPs
    have one degree of freedom between them: the box's yaw ψ about the vertical. Each edge
    pointing at ``ovps[k]`` within ``max_angle_deg`` constrains ψ through the plane it
    spans with the camera centre (normal ``n = Kᵀ l``): ``n · d_k(ψ) = 0``. Minimising
    ``Σ w (n · d_k(ψ))²`` over ψ, with ``w`` the edge's length, is the smallest
    eigenvector of a 2×2 matrix. Two nearly parallel edges of one face fix their own OVP
    poorly (a small error moves it far along and off the horizon); tied to the horizon
    and to the other face's edges it moves only along the horizon, and only as far as
    all edges allow.

    Inputs: ``legs`` M×4 segments (pixels), ``ovps`` 2×3 the current O1, O2 (homogeneous
    pixels), ``layout`` with V3 and the focal length. Returns 2×3 unit homogeneous O1, O2
    (same order), or None when either OVP has no edge to rest on.
    """
    return _fit_box_ovps(legs, ovps, layout.vps, layout.focal_px, layout.centre[0],
                         layout.centre[1], max_angle_deg)
