"""Layout vanishing points V1 (LMVP), V2, V3 and the segment → VP assignment (paper Fig. 2).

The paper takes the layout VPs from the authors' earlier work; this module uses a method
that needs no calibration beyond a rough focal length and never divides by zero:

1. **V3, vertical.** Near-vertical segments vote: every pairwise intersection of the
   longest ones, and the point at infinity straight down the image, is a hypothesis,
   scored MSAC-style by the length of the segments that point at it. The best few
   (``vertical_alternatives``) and straight down (a level camera) are each refined by
   least squares over their inliers and completed into a frame (steps 2–3); the frame
   with the most support, V3's and V1's and V2's together, is the layout. Straight down
   is also completed as it is, unrefined: below V2 the floor's lines look vertical and
   can lead its refinement several degrees astray; fitted to nothing, that frame must
   have a tenth more support to win. The layout's V1 × V2,
   the direction at a right angle to both, is then completed too and wins if better
   supported: below a camera pitched down, floor lines toward V2 look near-vertical, and
   a box's few short vertical edges may make no hypothesis of their own.
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
4. **Polish.** Until here a segment weighs on every VP whose thresholds it passes, so a
   family of edges a few degrees off a layout axis (a rotated obstacle, a road beside a
   building) pulls that VP. Each segment is now given to the one VP it points at best,
   layout or candidate (as :func:`assign_segments` labels them), and each observed
   layout VP is refined on its own segments. With a known focal length the last refit
   adds a soft prior that V1, V2, V3 are orthogonal within ``orthogonal_sigma_deg``
   (MAP): a VP its segments hardly fix, such as a horizontal VP near infinity, leans to
   the right angle with the others; one they fix stays put.

All VPs are homogeneous pixel coordinates (unit-norm 3-vectors); see
:mod:`companion.vision.geometry`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from companion.vision._vanishing import assign as _assign
from companion.vision._vanishing import layout_vps
from companion.vision.geometry import principal_point

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
    """Thresholds of the VP stage (pixels and degrees). ``range`` in a field's metadata is
    what the config accepts for it."""

    residual_px: float = field(default=2.0, metadata={"range": (0.1, 50.0)})
    """endpoint distance from the segment–VP line for an inlier"""
    max_angle_deg: float = field(default=4.0, metadata={"range": (0.1, 45.0)})
    """and at most this angle between segment and VP direction"""
    vertical_max_tilt_deg: float = field(default=25.0, metadata={"range": (1.0, 60.0)})
    """V3 candidates lean at most this far from image vertical"""
    vertical_hypothesis_segments: int = field(default=30, metadata={"range": (2, 200)})
    """longest candidates whose pairs are V3 hypotheses"""
    vertical_max_camera_tilt_deg: float = field(default=35.0, metadata={"range": (1.0, 89.0)})
    """V3 within this of the camera's down axis"""
    vertical_alternatives: int = field(default=4, metadata={"range": (1, 16)})
    """distinct V3 hypotheses each completed into a frame"""
    histogram_bin_deg: float = field(default=0.5, metadata={"range": (0.05, 10.0)})
    histogram_sigma_deg: float = field(default=1.0, metadata={"range": (0.05, 10.0)})
    peak_min_share: float = field(default=0.04, metadata={"range": (0.0, 1.0)})
    """a horizontal peak holds >= this share of horizontal length"""
    max_horizontal_vps: int = field(default=6, metadata={"range": (2, 20)})
    orthogonal_tol_deg: float = field(default=20.0, metadata={"range": (0.0, 45.0)})
    """V1 ⟂ V2 within this when the focal length is a guess"""
    known_focal_orthogonal_tol_deg: float = field(default=10.0, metadata={"range": (0.0, 45.0)})
    """... and when it is given"""
    min_vp_separation_deg: float = field(default=3.0, metadata={"range": (0.0, 45.0)})
    """peaks closer than this are one VP"""
    orthogonal_sigma_deg: float = field(default=0.0, metadata={"range": (0.0, 45.0)})
    """the final refit's prior that the layout VPs are orthogonal, to within this (0: none,
    as when the focal length is a guess)"""
    known_focal_orthogonal_sigma_deg: float = field(default=1.0, metadata={"range": (0.0, 45.0)})
    """... and when it is given"""


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
    centre = principal_point(width, height)
    vps, observed, support, others, others_support = layout_vps(
        segments, centre[0], centre[1], focal_px, p)
    return LayoutVPs(
        vps=vps,
        observed=observed,
        support_px=support,
        others=others,
        others_support_px=others_support,
        focal_px=float(focal_px),
        centre=centre,
    )


def assign_segments(segments: np.ndarray, vps: np.ndarray, params: VPParams | None = None):
    """Label each segment with the layout VP it points at: V1, V2, V3 or NONE (−1).

    ``vps`` is K×3 homogeneous pixel points; a segment goes to the most consistent VP
    that passes both thresholds of :class:`VPParams` (angle and endpoint residual).
    Returns (labels int array (N,), angle_deg (N,) to the chosen VP).
    """
    p = params or VPParams()
    return _assign(segments, vps, p.max_angle_deg, p.residual_px)
