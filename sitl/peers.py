"""Published vanishing-point detectors run beside ours, for ``companion eval --yud``.

Evaluation only, never a runtime dependency. The peer is ``lu-vp-detect`` (X. Lu, J. Yao,
H. Li, Y. Liu, "2-Line Exhaustive Searching for Real-Time Vanishing Point Estimation in
Manhattan World", WACV 2017). Its wheel requires ``opencv-contrib-python``, which would
overwrite our headless ``cv2``, so it is installed without its dependencies:

    .venv/bin/pip install --no-deps lu-vp-detect

It is written for OpenCV 4, whose LSD returns segments as an N×1×4 array; OpenCV 5 returns
N×4, so :class:`_LuVPDetection` replaces its line-detection step with the same LSD call and
length filter, shaped for either version.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

__all__ = ["LU_DEFAULT_FOCAL_PX", "PeerUnavailable", "lu_vp_detector"]

LU_INSTALL = "pip install --no-deps lu-vp-detect"
LU_DEFAULT_FOCAL_PX = 1500.0  # the peer's own default camera


class PeerUnavailable(RuntimeError):
    """The peer's package is not installed."""


def lu_vp_detector(focal_px: float, principal_point: tuple[float, float],
                   length_thresh_px: float = 30.0, seed: int = 0
                   ) -> Callable[[np.ndarray], np.ndarray]:
    """A function BGR image → 3×3 array of homogeneous VPs (rows ``[x, y, w]``, pixels).

    ``focal_px`` and ``principal_point`` are handed to the peer as its camera (it has no
    self-calibration; its own default focal length is 1500 px). ``length_thresh_px`` is its
    default minimum segment length; ``seed`` fixes its RANSAC so runs repeat.
    """
    try:
        from lu_vp_detect import VPDetection
    except ImportError as exc:  # optional extra
        raise PeerUnavailable(f"lu-vp-detect is not installed ({LU_INSTALL})") from exc

    class _LuVPDetection(VPDetection):
        # Replaces the name-mangled private ``VPDetection.__detect_lines``.
        def _VPDetection__detect_lines(self, img: np.ndarray) -> np.ndarray:
            gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
            found = cv2.createLineSegmentDetector(0).detect(gray)[0]
            lines = (np.zeros((0, 4), np.float32) if found is None
                     else np.asarray(found, np.float32).reshape(-1, 4))
            lengths = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
            lines = lines[lengths >= self.length_thresh]
            self._VPDetection__lines = lines
            return lines

    detector = _LuVPDetection(length_thresh=length_thresh_px,
                              principal_point=np.asarray(principal_point, np.float32),
                              focal_length=float(focal_px), seed=seed)

    k = np.array([[focal_px, 0.0, principal_point[0]],
                  [0.0, focal_px, principal_point[1]],
                  [0.0, 0.0, 1.0]])

    def detect(image: np.ndarray) -> np.ndarray:
        # find_vps returns 3-D directions (x right, y down, z forward) for the camera it
        # was given; through that camera they are homogeneous pixels, finite or not.
        dirs = np.asarray(detector.find_vps(image), dtype=float)
        return dirs @ k.T

    return detect
