"""Compiled loop of :func:`companion.vision.lines.extend_segments` (legs grown to their
junctions), which describes the rule."""

import numpy as np

from libc.math cimport floor, hypot, rint

# Where the grey-level step across a segment is sampled inside it (fractions of its length).
cdef double[::1] INSIDE = np.linspace(0.1, 0.9, 9)


cdef inline double bilinear(const unsigned char[:, ::1] img, double x, double y) noexcept nogil:
    """Grey level at (x, y), bilinear, edge pixels repeated beyond the border, rounded to
    an integer (as an 8-bit image resampled by OpenCV)."""
    cdef Py_ssize_t h = img.shape[0], w = img.shape[1]
    cdef double fx0 = floor(x), fy0 = floor(y)
    cdef double fx = x - fx0, fy = y - fy0
    cdef Py_ssize_t x0 = <Py_ssize_t>fx0, y0 = <Py_ssize_t>fy0
    cdef Py_ssize_t x1 = x0 + 1, y1 = y0 + 1
    x0 = 0 if x0 < 0 else (w - 1 if x0 > w - 1 else x0)
    x1 = 0 if x1 < 0 else (w - 1 if x1 > w - 1 else x1)
    y0 = 0 if y0 < 0 else (h - 1 if y0 > h - 1 else y0)
    y1 = 0 if y1 < 0 else (h - 1 if y1 > h - 1 else y1)
    return rint((img[y0, x0] * (1.0 - fx) + img[y0, x1] * fx) * (1.0 - fy)
                + (img[y1, x0] * (1.0 - fx) + img[y1, x1] * fx) * fy)


cdef inline double median9(double* v) noexcept nogil:
    """The median of nine values (sorted in place)."""
    cdef int a, b
    cdef double tmp
    for a in range(1, 9):
        b = a
        while b > 0 and v[b] < v[b - 1]:
            tmp = v[b]
            v[b] = v[b - 1]
            v[b - 1] = tmp
            b -= 1
    return v[4]


def grow_segments(gray, segments, ends, double max_px, double step_px, double offset_px,
                  double min_contrast, double keep_frac, double side_tol, double side_frac):
    """Each allowed end of each segment pushed out along its line, in steps of ``step_px``
    up to ``max_px``, while the edge continues: the step across it keeps its sign and
    ``keep_frac`` of its median inside (and ``min_contrast``), or one side keeps its
    median grey level inside within ``max(side_tol, side_frac · |median step|)`` and the
    other side differs from that median by more than ``side_tol``. ``ends`` N×2 bool or
    None (all). N×4 out."""
    cdef const unsigned char[:, ::1] img = np.ascontiguousarray(gray, dtype=np.uint8)
    out_arr = np.array(segments, dtype=float, copy=True).reshape(-1, 4)
    cdef double[:, ::1] s = out_arr
    cdef Py_ssize_t n = s.shape[0], i, k, e, count
    cdef Py_ssize_t t = <Py_ssize_t>(max_px // step_px)
    if n == 0 or t < 1:
        return out_arr
    cdef const unsigned char[:, ::1] allowed
    cdef bint every_end = ends is None
    if not every_end:
        allowed = np.ascontiguousarray(ends, dtype=bool).reshape(-1, 2).view(np.uint8)
    cdef double w_max = img.shape[1] - 1, h_max = img.shape[0] - 1
    cdef double dx, dy, length, ux, uy, nx, ny, x, y, along, need, sign, step, tol, va, vb
    cdef double side_a_median, side_b_median
    cdef double inside[9]
    cdef double side_a[9]
    cdef double side_b[9]
    cdef double grow[2]
    for i in range(n):
        if not (every_end or allowed[i, 0] or allowed[i, 1]):
            continue
        dx = s[i, 2] - s[i, 0]
        dy = s[i, 3] - s[i, 1]
        length = hypot(dx, dy)
        ux = dx / (length if length > 1e-9 else 1e-9)
        uy = dy / (length if length > 1e-9 else 1e-9)
        nx = -uy * offset_px
        ny = ux * offset_px
        for k in range(9):
            along = INSIDE[k] * length
            x = s[i, 0] + along * ux
            y = s[i, 1] + along * uy
            side_a[k] = bilinear(img, <float>(x + nx), <float>(y + ny))
            side_b[k] = bilinear(img, <float>(x - nx), <float>(y - ny))
            inside[k] = side_a[k] - side_b[k]
        step = median9(inside)
        side_a_median = median9(side_a)
        side_b_median = median9(side_b)
        sign = (step > 0) - (step < 0)
        need = <float>keep_frac * <float>abs(step)
        if need < min_contrast:
            need = min_contrast
        tol = side_frac * abs(step)
        if tol < side_tol:
            tol = side_tol
        for e in range(2):
            grow[e] = 0.0
            if sign == 0 or not (every_end or allowed[i, e]):
                continue
            count = 0
            for k in range(1, t + 1):
                along = -step_px * k if e == 0 else length + step_px * k
                x = s[i, 0] + along * ux
                y = s[i, 1] + along * uy
                if not (0.0 <= x <= w_max and 0.0 <= y <= h_max):
                    break
                va = bilinear(img, <float>(x + nx), <float>(y + ny))
                vb = bilinear(img, <float>(x - nx), <float>(y - ny))
                # The edge goes on with the same contrast, or, where the background behind
                # an occluding edge changes, with one side the same surface as inside and
                # the other side not that surface (more than side_tol from it: texture on
                # a floor seen past a corner differs by less).
                if not (sign * (va - vb) >= need
                        or (abs(va - side_a_median) <= tol
                            and abs(vb - side_a_median) > side_tol)
                        or (abs(vb - side_b_median) <= tol
                            and abs(va - side_b_median) > side_tol)):
                    break
                count += 1
            grow[e] = step_px * count
        s[i, 0] -= grow[0] * ux
        s[i, 1] -= grow[0] * uy
        s[i, 2] += grow[1] * ux
        s[i, 3] += grow[1] * uy
    return out_arr
