"""Straight line segments, the input of every later stage (paper eq. 1).

A segment is ``L_i = [x1, y1, x2, y2]`` in pixels. The paper fits lines to a contour
detector's output; any good segment detector will do. Two are offered:

- ``edlines``: EDLines (Akinlar & Topal 2011) from ``cv2.ximgproc.EdgeDrawing``; the
  default, several times faster than LSD on 640×480.
- ``lsd``: the LSD detector (von Gioi et al. 2012), ``cv2.createLineSegmentDetector``.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from companion.vision._lines import grow_segments, step_z
from companion.vision._lines import noise_sigma as _noise_sigma
from companion.vision._lines import refine_segments as _refine_segments
from companion.vision.geometry import segment_lengths

__all__ = ["DETECTORS", "make_detector", "to_gray", "filter_segments", "refine_segments",
           "extend_segments", "noise_sigma", "edge_step_z"]

Detector = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def to_gray(frame: np.ndarray) -> np.ndarray:
    """8-bit single-channel view of a BGR or grey frame."""
    if frame.ndim == 3 and frame.shape[2] == 3:
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    if frame.ndim == 3 and frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY)
    return frame if frame.dtype == np.uint8 else cv2.convertScaleAbs(frame)


def _edlines(min_length_px: float, edge_threshold: float, validate: bool = False) -> Detector:
    ed = cv2.ximgproc.createEdgeDrawing()
    params = cv2.ximgproc.EdgeDrawing.Params()
    params.MinLineLength = max(int(round(min_length_px)), 5)
    params.GradientThresholdValue = int(round(edge_threshold))
    params.NFAValidation = False
    ed.setParams(params)  # before the first detectEdges, which reads the threshold

    def lines(nfa: bool) -> np.ndarray:
        if params.NFAValidation != nfa:  # only a validating detector switches, each frame
            params.NFAValidation = nfa
            ed.setParams(params)
        found = ed.detectLines()
        return np.empty((0, 4)) if found is None else np.asarray(found, float).reshape(-1, 4)

    def detect(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ed.detectEdges(gray)
        segments = lines(False)
        if not validate:
            return segments, np.ones(len(segments), bool)
        # A-contrario validation (EDLines' NFA test) of the same edge chains: the lines
        # it keeps are rows of the unvalidated ones, so refitting costs no edge detection.
        kept = {row.tobytes() for row in lines(True)}
        return segments, np.array([row.tobytes() in kept for row in segments], bool)

    return detect


def _lsd(min_length_px: float, edge_threshold: float,  # noqa: ARG001
         validate: bool = False) -> Detector:  # noqa: ARG001
    lsd = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD)

    def detect(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        found = lsd.detect(gray)[0]
        # OpenCV 4 returns N×1×4, OpenCV 5 N×4; LSD validates every segment itself.
        segments = np.empty((0, 4)) if found is None else np.asarray(found, float).reshape(-1, 4)
        return segments, np.ones(len(segments), bool)

    return detect


DETECTORS: dict[str, Callable[[float, float, bool], Detector]] = {"edlines": _edlines,
                                                                  "lsd": _lsd}


def make_detector(name: str, min_length_px: float, edge_threshold: float = 20.0,
                  validate: bool = False) -> Detector:
    """A segment detector ``gray uint8 image → (N×4 float array [x1, y1, x2, y2], N bool)``:
    the segments and which of them pass an a-contrario test.

    The detector object is built once and reused for every frame (building it is not
    free). ``name`` is one of :data:`DETECTORS`. ``edge_threshold`` is EDLines' gradient
    threshold in grey levels. With ``validate`` each EDLines segment is put to its NFA test
    (a line is kept only if so many of its pixels' gradients are aligned with it that chance
    is an unlikely explanation), else every flag is True. LSD sets its threshold from its
    own noise model and validates every segment itself; it ignores both.
    """
    try:
        factory = DETECTORS[name]
    except KeyError:
        raise ValueError(
            f"unknown line detector {name!r}; choose from {sorted(DETECTORS)}"
        ) from None
    return factory(min_length_px, edge_threshold, validate)


def filter_segments(segments: np.ndarray, min_length_px: float, max_count: int) -> np.ndarray:
    """Segments at least ``min_length_px`` long, the ``max_count`` longest kept.

    Keeping the longest bounds every later stage (corner and pair search grow with the
    number of segments) and drops the short, noisy ones first.
    """
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    lengths = segment_lengths(s)
    long_enough = lengths >= min_length_px
    if len(s) <= max_count and long_enough.all():  # the detector's own minimum held
        return s
    keep = np.flatnonzero(long_enough)
    if len(keep) > max_count:
        keep = keep[np.argsort(-lengths[keep], kind="stable")[:max_count]]
        keep.sort()
    return s[keep]


def refine_segments(gray: np.ndarray, segments: np.ndarray, smooth_sigma_px: float = 0.7,
                    half_px: int = 2, step_px: float = 2.0, min_stations: int = 8,
                    max_stations: int = 16, max_shift_px: float = 1.5,
                    min_share: float = 0.5, outlier_px: float = 0.75,
                    min_contrast: float = 8.0) -> np.ndarray:
    """Segments moved onto the gradient peak of their edge, to a fraction of a pixel.

    A detector fits its line to edge pixels on whole-pixel positions; over a short
    segment that leaves its angle a degree or so off, and every VP, OVP and corner is an
    intersection of such lines. Here the grey profile across the segment (``gray``
    smoothed by a Gaussian of ``smooth_sigma_px``) is read at stations along it on whole
    pixels of its major axis, at least ``step_px`` apart, ``min_stations`` to
    ``max_stations`` of them; the derivative's peak within ``half_px`` of the segment
    (central differences 2 px apart, at least ``min_contrast`` grey levels: noise on a
    flat surface has peaks too), refined by a parabola, is the edge at each station, and
    a weighted straight-line fit through the peaks (refitted without those more than
    ``outlier_px`` off) is the new segment. Its ends keep their places along it.

    Segments too short for ``min_stations`` keep the detector's fit: over a handful of
    stations the peaks' own noise outweighs the gain. A segment is also left as it is
    when fewer than ``min_share`` of its stations show a peak, or when an end would move
    more than ``max_shift_px`` (the peak found is another edge's).

    Measured against the true VPs (docs/evaluation.md, "Sub-pixel segments"), segments
    of 20–50 px point at their VP 20–35 % more precisely.

    Inputs: ``gray`` H×W uint8, ``segments`` N×4 pixels. Output: N×4, same order.
    """
    smooth = cv2.GaussianBlur(gray, (0, 0), smooth_sigma_px) if smooth_sigma_px > 0 else gray
    return _refine_segments(smooth, segments, half_px, step_px, min_stations, max_stations,
                            max_shift_px, min_share, outlier_px, min_contrast)


def extend_segments(gray: np.ndarray, segments: np.ndarray, max_px: float = 24.0,
                    step_px: float = 2.0, offset_px: float = 2.0, min_contrast: float = 4.0,
                    keep_frac: float = 0.5, side_tol: float = 8.0, side_frac: float = 0.25,
                    ends: np.ndarray | None = None) -> np.ndarray:
    """Segments grown along their own line for as long as the image still shows their edge.

    Line detectors stop a few pixels short of junctions, where the gradient turns, but a
    corner projection (eq. 2) needs legs that reach the junction. The grey levels either
    side of each segment (``offset_px`` away) are sampled inside it and every ``step_px``
    beyond each end; an end moves out, up to ``max_px``, while the edge goes on:

    - the step across it keeps the segment's sign and at least ``keep_frac`` of its
      median size inside (and ``min_contrast`` grey levels); or
    - one side keeps its median grey level inside, within ``max(side_tol, side_frac ·
      |median step|)``, and the other side differs from that grey level by more than
      ``side_tol``: the edge of an object whose background changes (wall, then skirting
      board, then floor).

    Photometric evidence, so a leg is not stretched to a junction that is not in the
    image; past a box's convex corner both sides turn into one surface and growth stops.

    Inputs: ``gray`` H×W uint8, ``segments`` N×4 pixels, ``ends`` N×2 bool: which ends
    may grow (default all). Output: N×4, same order.
    """
    return grow_segments(gray, segments, ends, max_px, step_px, offset_px, min_contrast,
                         keep_frac, side_tol, side_frac)


QUANTISATION_SIGMA = 12 ** -0.5
"""grey levels: the noise of rounding to 8 bits alone, the least :func:`noise_sigma` gives"""


def noise_sigma(gray: np.ndarray, positions: int = 10_000) -> float:
    """The standard deviation of the frame's sensor noise, in grey levels.

    Immerkær's estimator (J. Immerkær, *Fast noise variance estimation*, CVIU 1996): the
    mean absolute response to a mask that cancels every grey level varying linearly, so
    that on a plain surface only the noise answers. The mask's taps are 2 px apart, so a
    slight blur (demosaicing, a lens) does not correlate them, and it is read at about
    ``positions`` places (every other column of evenly spaced rows, counted from each
    border towards the middle, so that a mirrored frame gives the same σ): enough for one
    number to a few per cent, at the same cost at any frame size. Texture and edges
    answer too, so on a textured frame the estimate errs high (the test it serves then
    errs towards keeping segments).

    Input: ``gray`` H×W uint8. Output: σ >= :data:`QUANTISATION_SIGMA`.
    """
    h, w = gray.shape[:2]
    row_step = max(1, round(h * w / 2 / positions))
    return max(float(_noise_sigma(gray, row_step)), QUANTISATION_SIGMA)


def edge_step_z(gray: np.ndarray, segments: np.ndarray, sigma: float,
                step_px: float = 2.0) -> np.ndarray:
    """How clearly each segment is an edge: its grey step across, in standard errors of
    the frame's noise.

    At stations every ``step_px`` along the segment (2 to 64 of them) the mean grey level
    1 and 2 px to one side minus that to the other is read (bilinear); on a surface with
    no edge each such difference is noise of standard deviation about ``sigma``, and the
    median of ``m`` of them (the mean of the middle two when ``m`` is even, so that the
    segment's direction does not matter) has a standard error of
    ``1.2533 sigma / sqrt(m)``. The result is the median's size in those units: a long
    faint edge and a short strong one
    both score high, a chain of noise pixels that a detector fitted a line to does not.

    Inputs: ``gray`` H×W uint8, ``segments`` N×4 pixels, ``sigma`` grey levels (from
    :func:`noise_sigma`). Output: N non-negative floats.
    """
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    return step_z(gray, s, max(float(sigma), QUANTISATION_SIGMA), float(step_px))
