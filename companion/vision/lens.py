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
"""

from __future__ import annotations

import cv2
import numpy as np

from companion.vision.geometry import principal_point

__all__ = ["camera_matrix", "undistort_maps", "distort_px"]


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


def distort_px(points: np.ndarray, width: int, height: int, focal_px: float,
               distortion) -> np.ndarray:
    """Where the raw frame shows pinhole pixels: OpenCV's forward model.

    Inputs: ``points`` N×2 pixels of the pinhole picture; the camera as for
    :func:`undistort_maps`. Output: N×2 pixels of the frame taken through the lens.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    k1, k2, p1, p2, k3 = _coeffs(distortion)
    c = principal_point(width, height)
    x, y = ((p - c) / focal_px).T
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1) * focal_px + c
