"""Inline C geometry shared by the compiled stages (``_*.pyx``).

The same quantities as :mod:`companion.vision.geometry`, for one segment or one point at a
time, so the loops of the later stages run without a numpy call per step. Points and lines
are homogeneous 3-vectors; nothing divides by ``w``.
"""

from libc.math cimport acos, asin, fabs, sqrt

cdef inline double hypot(double x, double y) noexcept nogil:
    """``sqrt(x² + y²)``. libm's ``hypot`` guards against overflow and underflow at several
    times the cost; pixel and normalised camera coordinates come nowhere near either, and
    the pipeline takes thousands of these a frame."""
    return sqrt(x * x + y * y)


cdef inline double degrees(double radians) noexcept nogil:
    return radians * 57.29577951308232


cdef inline double radians(double degrees) noexcept nogil:
    return degrees * 0.017453292519943295


cdef inline void cross3(const double* a, const double* b, double* out) noexcept nogil:
    """``out = a × b``: the line through two points, or the point on two lines."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


cdef inline double norm3(const double* a) noexcept nogil:
    return sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


cdef inline double unit3(double* a) noexcept nogil:
    """Scale ``a`` to unit norm in place (left as is when zero); returns the old norm."""
    cdef double n = norm3(a)
    if n > 0:
        a[0] /= n
        a[1] /= n
        a[2] /= n
    return n


cdef inline double dot3(const double* a, const double* b) noexcept nogil:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


cdef inline void segment_line(double x1, double y1, double x2, double y2,
                              double* out) noexcept nogil:
    """The line through a segment, scaled so ``a² + b² = 1``: ``line · (x, y, 1)`` is the
    signed distance in pixels from (x, y) to it."""
    out[0] = y1 - y2
    out[1] = x2 - x1
    out[2] = x1 * y2 - x2 * y1
    cdef double n = hypot(out[0], out[1])
    if n > 0:
        out[0] /= n
        out[1] /= n
        out[2] /= n
    else:
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0


cdef inline double vp_sin(double x1, double y1, double x2, double y2,
                          const double* v) noexcept nogil:
    """|sin| of the angle between a segment and the direction from its midpoint to the
    homogeneous point ``v``; 1 when that is undefined (the midpoint at ``v``)."""
    cdef double ux = x2 - x1, uy = y2 - y1
    cdef double tx = v[0] - v[2] * (0.5 * (x1 + x2))
    cdef double ty = v[1] - v[2] * (0.5 * (y1 + y2))
    cdef double denom = hypot(ux, uy) * hypot(tx, ty)
    if denom <= 1e-12:
        return 1.0
    cdef double s = fabs(ux * ty - uy * tx) / denom
    return 1.0 if s > 1.0 else s


cdef inline double end_distance(double[:, ::1] s, Py_ssize_t i, double x,
                                double y) noexcept nogil:
    """Distance from (x, y) to the nearer endpoint of segment ``s[i]``."""
    cdef double a = hypot(s[i, 0] - x, s[i, 1] - y)
    cdef double b = hypot(s[i, 2] - x, s[i, 3] - y)
    return a if a < b else b


cdef inline double endpoint_weight(const double* s, const double* v) noexcept nogil:
    """``(L / |t|)²`` for segment ``s`` (x1, y1, x2, y2), ``t`` from its midpoint to ``v``
    scaled to unit norm: the weight that turns the algebraic residual ``l·v`` of a VP fit
    into endpoint residuals, so segments near a finite VP do not dominate the fit."""
    cdef double v2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    cdef double tx = v[0] - v[2] * (0.5 * (s[0] + s[2]))
    cdef double ty = v[1] - v[2] * (0.5 * (s[1] + s[3]))
    cdef double t2 = tx * tx + ty * ty
    if t2 < 1e-24 * v2:
        t2 = 1e-24 * v2
    return ((s[2] - s[0]) * (s[2] - s[0]) + (s[3] - s[1]) * (s[3] - s[1])) * v2 / t2


cdef inline void pixel_point(double f, double cx, double cy, const double* d,
                             double* out) noexcept nogil:
    """Unit homogeneous pixel point ``K d`` of a 3-D direction (``out`` may be ``d``)."""
    out[0] = f * d[0] + cx * d[2]
    out[1] = f * d[1] + cy * d[2]
    out[2] = d[2]
    unit3(out)


cdef inline double vp_angle_deg(double sin_value) noexcept nogil:
    return degrees(asin(sin_value))


cdef inline double angle_between_deg(const double* a, const double* b) noexcept nogil:
    """Angle between undirected 3-D directions ``a`` and ``b`` (unit), in [0°, 90°]."""
    cdef double c = fabs(dot3(a, b))
    if c > 1.0:
        c = 1.0
    return degrees(acos(c))


cdef inline void smallest_eigenvector(double* a, double* out) noexcept nogil:
    """Unit eigenvector of the smallest eigenvalue of the symmetric 3×3 ``a`` (row-major,
    overwritten): cyclic Jacobi rotations, accurate to rounding for any input."""
    cdef double v[9]
    cdef int i, j, k, p, q, sweep, best
    cdef double apq, theta, t, c, s, tau, app, aqq, akp, akq, off
    for i in range(9):
        v[i] = 0.0
    v[0] = 1.0
    v[4] = 1.0
    v[8] = 1.0
    for sweep in range(50):
        off = a[1] * a[1] + a[2] * a[2] + a[5] * a[5]
        if off <= 1e-300:
            break
        for p in range(2):
            for q in range(p + 1, 3):
                apq = a[3 * p + q]
                if apq == 0.0:
                    continue
                app = a[3 * p + p]
                aqq = a[3 * q + q]
                theta = (aqq - app) / (2.0 * apq)
                t = (1.0 if theta >= 0 else -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0))
                c = 1.0 / sqrt(t * t + 1.0)
                s = t * c
                tau = s / (1.0 + c)
                a[3 * p + p] = app - t * apq
                a[3 * q + q] = aqq + t * apq
                a[3 * p + q] = 0.0
                a[3 * q + p] = 0.0
                for k in range(3):
                    if k != p and k != q:
                        akp = a[3 * k + p]
                        akq = a[3 * k + q]
                        a[3 * k + p] = akp - s * (akq + tau * akp)
                        a[3 * p + k] = a[3 * k + p]
                        a[3 * k + q] = akq + s * (akp - tau * akq)
                        a[3 * q + k] = a[3 * k + q]
                for k in range(3):
                    akp = v[3 * k + p]
                    akq = v[3 * k + q]
                    v[3 * k + p] = akp - s * (akq + tau * akp)
                    v[3 * k + q] = akq + s * (akp - tau * akq)
    best = 0
    for i in range(1, 3):
        if a[4 * i] < a[4 * best]:
            best = i
    for i in range(3):
        out[i] = v[3 * i + best]
    unit3(out)
