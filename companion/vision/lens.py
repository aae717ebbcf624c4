"""Lens distortion, undone before the line detector sees a frame.

The method assumes a pinhole: a straight edge in the room is a straight segment in the
picture, and a VP's pixel position is a bearing through the focal length (eq. 10). A
wide lens bends the edges near the frame's border (barrel distortion), which tilts their
segments away from the VPs they belong to, scatters the layout VPs and leaves room edges
looking like an obstacle's.

The model is OpenCV's radial–tangential one, with the coefficients in the order
``cv2.calibrateCamera`` returns them: ``(k1, k2, p1, p2[, k3])``, any prefix of it, on
coordinates normalised by the focal length; the principal point is the frame centre
(:func:`~companion.vision.geometry.principal_point`), as everywhere in the pipeline.

A lens that was not given is estimated (:func:`radial_k`) with one radial coefficient on
coordinates normalised by the half-diagonal instead, so that it needs no focal length:
``undistort_maps(w, h, half_diagonal(w, h), (k,))`` undoes it.
"""

from __future__ import annotations

import cv2
import numpy as np

from companion.vision.geometry import principal_point, segment_lengths
from companion.vision.vanishing import VPParams, assign_segments, detect_layout_vps

__all__ = ["camera_matrix", "undistort_maps", "distort_maps", "distort_px", "half_diagonal",
           "undistort_segments", "straightness_cost", "radial_k"]

RADIAL_K_COARSE = tuple(round(0.10 - 0.05 * i, 2) for i in range(15))
"""the radial coefficients (half-diagonal normalised) :func:`radial_k` tries first: from a
mild pincushion (+0.10) to a strong barrel (−0.60: a pinhole point at the end of the
half-diagonal is drawn 60 % of the way in)"""

RADIAL_K_STEP = 0.01
"""then every this much within half a coarse step of the best"""

STRAIGHTNESS_CAP_DEG = 2.0
"""a segment further than this from every layout VP counts as this far (not room)"""


def camera_matrix(width: int, height: int, focal_px: float) -> np.ndarray:
    """3×3 intrinsic matrix: focal length ``focal_px`` (pixels), square pixels, the
    principal point at the frame centre."""
    cx, cy = principal_point(width, height)
    return np.array([[focal_px, 0.0, cx], [0.0, focal_px, cy], [0.0, 0.0, 1.0]])


def _coeffs(distortion) -> np.ndarray:
    """OpenCV's five coefficients from any prefix of them."""
    c = np.zeros(5)
    d = np.asarray(distortion, dtype=float).ravel()[:5]
    c[: len(d)] = d
    return c


def undistort_maps(width: int, height: int, focal_px: float,
                   distortion) -> tuple[np.ndarray, np.ndarray]:
    """Maps for ``cv2.remap`` that turn a frame of ``width``×``height`` taken through the
    lens into the pinhole picture of the same size and focal length ``focal_px``.

    ``distortion``: OpenCV's coefficients ``(k1, k2, p1, p2, k3)`` or a prefix of them.
    Returns the fixed-point map pair (``CV_16SC2``), built once per camera: remapping
    with it is one table lookup and a bilinear blend per pixel.
    """
    k = camera_matrix(width, height, focal_px)
    return cv2.initUndistortRectifyMap(k, _coeffs(distortion), None, k, (width, height),
                                       cv2.CV_16SC2)


def distort_maps(width: int, height: int, focal_px: float,
                 distortion) -> tuple[np.ndarray, np.ndarray]:
    """The other way from :func:`undistort_maps`: maps for ``cv2.remap`` that take a pinhole
    picture through the lens, as a camera with it would (for simulations and tests).
    Returns float32 maps: for each pixel of the lens's frame, the pinhole pixel it shows."""
    k = camera_matrix(width, height, focal_px)
    uv = np.stack(np.meshgrid(np.arange(width, dtype=np.float32),
                              np.arange(height, dtype=np.float32)), axis=-1)
    src = cv2.undistortPoints(uv.reshape(-1, 1, 2), k, _coeffs(distortion), P=k)
    src = src.reshape(height, width, 2)
    return np.ascontiguousarray(src[..., 0]), np.ascontiguousarray(src[..., 1])


def distort_px(points: np.ndarray, width: int, height: int, focal_px: float,
               distortion) -> np.ndarray:
    """Where the raw frame shows pinhole pixels: OpenCV's forward model
    (``cv2.projectPoints`` of the rays through them).

    Inputs: ``points`` N×2 pixels of the pinhole picture; the camera as for
    :func:`undistort_maps`. Output: N×2 pixels of the frame taken through the lens.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) == 0:
        return p
    rays = np.column_stack([(p - principal_point(width, height)) / focal_px, np.ones(len(p))])
    seen, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3),
                                camera_matrix(width, height, focal_px), _coeffs(distortion))
    return seen.reshape(-1, 2)


def half_diagonal(width: int, height: int) -> float:
    """Half the frame's diagonal in pixels: the unit of :func:`radial_k`'s coefficient."""
    return float(np.hypot(width, height)) / 2.0


def undistort_segments(segments: np.ndarray, width: int, height: int, k: float) -> np.ndarray:
    """Segment endpoints (N×4 pixels) of a frame taken through a radial lens ``k`` (OpenCV's
    k1 on coordinates normalised by :func:`half_diagonal`) → the pinhole picture's.

    An edge the lens bent is found as a chain of short segments; their endpoints lie on
    the bent edge, so undone they lie on the straight one."""
    s = np.ascontiguousarray(segments, dtype=float).reshape(-1, 4)
    if k == 0.0 or len(s) == 0:
        return s
    cam = camera_matrix(width, height, half_diagonal(width, height))
    return cv2.undistortPoints(s.reshape(-1, 1, 2), cam, _coeffs((k,)), P=cam).reshape(-1, 4)


def straightness_cost(segments: np.ndarray, width: int, height: int, focal_px: float,
                      params: VPParams | None = None,
                      weights: np.ndarray | None = None) -> float:
    """How badly ``segments`` (N×4, pixels) point at the room's layout VPs: the weighted
    mean squared angle (degrees²) of each segment to the nearest observed VP found among
    them, each angle truncated at :data:`STRAIGHTNESS_CAP_DEG`. ``weights`` (N) default to
    the segments' lengths.

    Under the right lens model the room's edges, undone, meet at three points; under a
    wrong one the edges far from the centre tilt away from them."""
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    lengths = segment_lengths(s) if weights is None else np.asarray(weights, dtype=float)
    if lengths.sum() <= 0:
        return float(STRAIGHTNESS_CAP_DEG ** 2)
    p = params or VPParams()
    layout = detect_layout_vps(s, width, height, focal_px, p)
    observed = layout.vps[np.array(layout.observed)]
    if len(observed) == 0:
        return float(STRAIGHTNESS_CAP_DEG ** 2)
    any_angle = VPParams(max_angle_deg=90.0, residual_px=float("inf"))
    _, angle = assign_segments(s, observed, any_angle)
    a = np.minimum(angle, STRAIGHTNESS_CAP_DEG)
    return float(np.sum(lengths * a * a) / lengths.sum())


def radial_k(segments: np.ndarray, width: int, height: int, focal_px: float,
             params: VPParams | None = None) -> float | None:
    """One frame's estimate of the lens's radial coefficient (half-diagonal normalised):
    the ``k`` whose undone segments have the least :func:`straightness_cost`, searched over
    :data:`RADIAL_K_COARSE`, then every :data:`RADIAL_K_STEP` within half a coarse step of
    the best.

    Inputs: ``segments`` N×4 pixels as detected in the frame, its size, a focal length
    (pixels; a guess is enough, it only sets how the VP stage checks orthogonality).
    Output: ``k`` (0 for a pinhole; < 0 barrel; of equally good ones the nearest 0), None
    when no ``k`` shows the room's layout. One frame holds little bend: on a
    video, the median of several frames' estimates is the lens
    (:class:`~companion.vision.pipeline.RunningLens`).
    """
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    # Weighted by their lengths as seen: undoing a strong barrel stretches the border's
    # segments into near-radial lines that all point at the centre.
    lengths = segment_lengths(s)

    def cost(k: float) -> float:
        return straightness_cost(undistort_segments(s, width, height, k), width, height,
                                 focal_px, params, lengths)

    costs = {k: cost(k) for k in RADIAL_K_COARSE}
    if len(set(costs.values())) == 1:
        return None

    def rank(k: float) -> tuple[float, float]:
        return costs[k], abs(k)

    best = min(costs, key=rank)
    half = abs(RADIAL_K_COARSE[1] - RADIAL_K_COARSE[0]) / 2.0
    n = int(half / RADIAL_K_STEP + 1e-9)
    for k in (round(best + i * RADIAL_K_STEP, 3) for i in range(-n, n + 1)):
        if k not in costs:
            costs[k] = cost(k)
    return float(min(costs, key=rank))
