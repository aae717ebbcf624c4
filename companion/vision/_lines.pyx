"""Compiled loops of :mod:`companion.vision.lines` (legs grown to their junctions,
segments moved onto their edges, each segment's step against the frame's noise), whose
functions describe the rules."""

import numpy as np

from libc.math cimport ceil, floor, rint, sqrt

from companion.vision._geometry cimport hypot

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


cdef double select_kth(double* v, Py_ssize_t n, Py_ssize_t k) noexcept nogil:
    """The k-th smallest of ``v[0:n]`` (Hoare's selection; ``v`` reordered in place)."""
    cdef Py_ssize_t lo = 0, hi = n - 1, a, b
    cdef double pivot, tmp
    while lo < hi:
        pivot = v[(lo + hi) // 2]
        a, b = lo, hi
        while a <= b:
            while v[a] < pivot:
                a += 1
            while v[b] > pivot:
                b -= 1
            if a <= b:
                tmp = v[a]
                v[a] = v[b]
                v[b] = tmp
                a += 1
                b -= 1
        if k <= b:
            hi = b
        elif k >= a:
            lo = a
        else:
            return v[k]
    return v[k]


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
        step = select_kth(inside, 9, 4)
        side_a_median = select_kth(side_a, 9, 4)
        side_b_median = select_kth(side_b, 9, 4)
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


cdef enum:
    MAX_PROFILE = 64  # longest grey profile across a segment


def refine_segments(smooth, segments, Py_ssize_t half_px, double step_px,
                    Py_ssize_t min_stations, Py_ssize_t max_stations, double max_shift_px,
                    double min_share, double outlier_px, double min_contrast):
    """Each segment moved onto its edge's gradient peak, as a straight line.

    Stations lie on whole pixels along the segment's major axis (x for a segment nearer
    horizontal, else y), in its middle 90 %, every ``step_px`` or farther apart so that
    there are at most ``max_stations``. At each, the grey profile across the minor axis
    is read on whole pixels within ``half_px + 1`` of the segment and differentiated
    (central differences); the peak of the derivative in the segment's polarity, refined
    by a parabola through its neighbours, is the edge there, if it rises to
    ``min_contrast`` grey levels (noise on a flat surface has peaks too). No
    interpolation: reading along a pixel column (or row) keeps it cheap. A line
    ``minor = a + b · major`` is fitted to the peaks by least squares, weighted by the
    peak's height, twice: without peaks lower than a quarter of the mean height, then also
    without peaks farther than ``outlier_px`` (across the line) from the first fit. The
    ends move onto that line, each to its nearest point. A segment is left as it is when
    fewer than ``min_share`` of its stations give a peak inside the window, or when an end
    would move more than ``max_shift_px``.

    ``smooth``: H×W uint8 (a lightly smoothed grey frame); ``segments`` N×4 pixels.
    N×4 out, same order.
    """
    cdef const unsigned char[:, ::1] img = np.ascontiguousarray(smooth, dtype=np.uint8)
    out_arr = np.array(segments, dtype=float, copy=True).reshape(-1, 4)
    cdef double[:, ::1] s = out_arr
    cdef Py_ssize_t n = s.shape[0], i, j, k, m, kk, best, stations, used, station, centre
    cdef Py_ssize_t count = 2 * half_px + 3, nd = 2 * half_px + 1
    cdef Py_ssize_t rows = img.shape[0], cols = img.shape[1], major_len, minor_len
    if (n == 0 or count > MAX_PROFILE or half_px < 1 or min_stations < 3
            or max_stations < min_stations):
        return out_arr
    cdef double grey[MAX_PROFILE]
    cdef double p0, q0, p1, q1, slope, lo, hi, span, spacing, minor, tot, sign, a, b, c, den
    cdef double sub, sw, swt, swtt, swo, swto, det, fa, fb, wmean, across, ex, ey, nrm
    cdef bint x_major
    offs_arr = np.empty(max_stations)
    wts_arr = np.empty(max_stations)
    ts_arr = np.empty(max_stations)
    der_arr = np.empty((max_stations, nd))
    cdef double[::1] offs = offs_arr, wts = wts_arr, ts = ts_arr
    cdef double[:, ::1] der = der_arr
    for i in range(n):
        x_major = abs(s[i, 2] - s[i, 0]) >= abs(s[i, 3] - s[i, 1])
        # (p, q): (major, minor) coordinates of the two ends, p0 <= p1.
        if x_major:
            p0, q0, p1, q1 = s[i, 0], s[i, 1], s[i, 2], s[i, 3]
            major_len, minor_len = cols, rows
        else:
            p0, q0, p1, q1 = s[i, 1], s[i, 0], s[i, 3], s[i, 2]
            major_len, minor_len = rows, cols
        if p1 < p0:
            p0, q0, p1, q1 = p1, q1, p0, q0
        span = p1 - p0
        if span < 4.0:
            continue
        slope = (q1 - q0) / span
        across = 1.0 / sqrt(1.0 + slope * slope)  # minor-axis distance → distance across
        lo = ceil(p0 + 0.05 * span)
        hi = floor(p1 - 0.05 * span)
        stations = <Py_ssize_t>((hi - lo) / step_px) + 1
        if stations < min_stations:
            continue
        if stations > max_stations:
            stations = max_stations
        spacing = floor((hi - lo) / (stations - 1))
        if spacing < 1.0:
            continue
        # The derivative profiles, and the segment's polarity from their centres.
        tot = 0.0
        used = 0
        for j in range(stations):
            station = <Py_ssize_t>(lo + spacing * j)
            if station < 0 or station >= major_len:
                continue
            minor = q0 + slope * (station - p0)
            centre = <Py_ssize_t>floor(minor + 0.5)
            if centre - half_px - 1 < 0 or centre + half_px + 1 >= minor_len:
                continue
            for k in range(count):
                grey[k] = (img[centre - half_px - 1 + k, station] if x_major
                           else img[station, centre - half_px - 1 + k])
            for k in range(nd):
                der[used, k] = grey[k + 2] - grey[k]
            tot += der[used, half_px]
            ts[used] = station
            offs[used] = centre - minor  # the window's centre, from the segment's line
            used += 1
        if used < min_share * stations:
            continue
        sign = 1.0 if tot >= 0.0 else -1.0
        # Each station's peak, sub-pixel, as an offset along the minor axis from the line.
        m = 0
        for j in range(used):
            best = 0
            for k in range(1, nd):
                if sign * der[j, k] > sign * der[j, best]:
                    best = k
            if best == 0 or best == nd - 1:
                continue
            a = sign * der[j, best - 1]
            b = sign * der[j, best]
            c = sign * der[j, best + 1]
            if b < min_contrast:
                continue
            den = a - 2.0 * b + c
            sub = 0.5 * (a - c) / den if den < 0.0 else 0.0
            sub = -0.5 if sub < -0.5 else (0.5 if sub > 0.5 else sub)
            offs[m] = offs[j] + (best - half_px) + sub
            wts[m] = b
            ts[m] = ts[j] - p0
            m += 1
        used = m
        if used < min_share * stations:
            continue
        wmean = 0.0
        for j in range(used):
            wmean += wts[j]
        wmean /= used
        fa = fb = 0.0
        for kk in range(2):
            sw = swt = swtt = swo = swto = 0.0
            m = 0
            for j in range(used):
                if wts[j] < 0.25 * wmean:
                    continue
                if kk == 1 and abs(offs[j] - (fa + fb * ts[j])) * across > outlier_px:
                    continue
                sw += wts[j]
                swt += wts[j] * ts[j]
                swtt += wts[j] * ts[j] * ts[j]
                swo += wts[j] * offs[j]
                swto += wts[j] * ts[j] * offs[j]
                m += 1
            det = sw * swtt - swt * swt
            if m < min_share * stations or det <= 1e-12 * sw * sw * span * span:
                m = 0
                break
            fb = (sw * swto - swt * swo) / det
            fa = (swo - fb * swt) / sw
        if m == 0:
            continue
        # The fitted line in (major, minor): minor = q0 + fa + (slope + fb) (major - p0);
        # each end moves to its nearest point on it.
        if abs(fa) * across > max_shift_px or abs(fa + fb * span) * across > max_shift_px:
            continue
        b = slope + fb
        nrm = 1.0 / sqrt(1.0 + b * b)
        for k in range(2):
            ex = s[i, 2 * k] if x_major else s[i, 2 * k + 1]  # major
            ey = s[i, 2 * k + 1] if x_major else s[i, 2 * k]  # minor
            c = (q0 + fa + b * (ex - p0) - ey) * nrm  # signed distance across, ...
            ex -= c * b * nrm  # ... and the foot of the perpendicular
            ey += c * nrm
            if x_major:
                s[i, 2 * k], s[i, 2 * k + 1] = ex, ey
            else:
                s[i, 2 * k], s[i, 2 * k + 1] = ey, ex
    return out_arr


cdef enum:
    MAX_STATIONS = 64  # most stations of the step test along one segment


cdef inline long immerkaer(const unsigned char[:, ::1] img, Py_ssize_t y,
                           Py_ssize_t x) noexcept nogil:
    """|mask response| at (x, y): 1 −2 1 / −2 4 −2 / 1 −2 1 with taps 2 px apart."""
    cdef long r = (4 * img[y, x] - 2 * (img[y - 2, x] + img[y + 2, x] + img[y, x - 2]
                                        + img[y, x + 2])
                   + img[y - 2, x - 2] + img[y - 2, x + 2] + img[y + 2, x - 2]
                   + img[y + 2, x + 2])
    return r if r >= 0 else -r


def noise_sigma(gray, Py_ssize_t row_step):
    """Immerkær's estimate (mask 1 −2 1 / −2 4 −2 / 1 −2 1, spacing 2 px) of the noise's
    standard deviation, on every ``row_step``-th row and every other column. Grey levels.

    The columns are every other one counted from each side's border towards the middle,
    so the set is its own mirror image: a frame and its mirror image give the same σ (every
    other column from the left would be the even columns of one and the odd of the other,
    and σ, through the noise test, would make the pipeline's answers differ)."""
    cdef const unsigned char[:, ::1] img = np.ascontiguousarray(gray, dtype=np.uint8)
    cdef Py_ssize_t h = img.shape[0], w = img.shape[1], x, y
    cdef long total = 0, count = 0
    for y in range(2, h - 2, row_step):
        x = 2
        while 2 * x <= w - 1 and x <= w - 3:  # the left half, x = 2, 4, …
            total += immerkaer(img, y, x)
            count += 1
            x += 2
        x = w - 3
        while 2 * x > w - 1 and x >= 2:  # the right half, its mirror: w − 1 − x = 2, 4, …
            total += immerkaer(img, y, x)
            count += 1
            x -= 2
    if count == 0:
        return 0.0
    return sqrt(np.pi / 2.0) * total / (6.0 * count)


def step_z(gray, segments, double sigma, double step_px):
    """Per segment: the median over stations (every ``step_px`` along it, 2 to
    ``MAX_STATIONS``) of the mean grey level 1 and 2 px to its left minus that to its
    right, in standard errors of that median on a surface without an edge,
    ``1.2533 sigma / sqrt(stations)``. N float out."""
    cdef const unsigned char[:, ::1] img = np.ascontiguousarray(gray, dtype=np.uint8)
    cdef const double[:, ::1] s = np.ascontiguousarray(segments, dtype=float).reshape(-1, 4)
    cdef Py_ssize_t n = s.shape[0], i, k, m
    out_arr = np.zeros(n)
    cdef double[::1] out = out_arr
    cdef double diff[MAX_STATIONS]
    cdef double dx, dy, length, ux, uy, x, y, med, lower
    for i in range(n):
        dx = s[i, 2] - s[i, 0]
        dy = s[i, 3] - s[i, 1]
        length = hypot(dx, dy)
        if length < 1e-9:
            continue
        ux = dx / length
        uy = dy / length
        m = <Py_ssize_t>floor(length / step_px)
        m = 2 if m < 2 else (MAX_STATIONS if m > MAX_STATIONS else m)
        for k in range(m):
            x = s[i, 0] + dx * (k + 0.5) / m
            y = s[i, 1] + dy * (k + 0.5) / m
            # the normal (-uy, ux) points to the segment's left
            diff[k] = 0.5 * (bilinear(img, x - uy, y + ux)
                             + bilinear(img, x - 2 * uy, y + 2 * ux)
                             - bilinear(img, x + uy, y - ux)
                             - bilinear(img, x + 2 * uy, y - 2 * ux))
        med = select_kth(diff, m, m // 2)
        if m % 2 == 0:  # the mean of the middle two: the upper one alone would change
            # with the segment's direction (a mirrored frame's segment sees the
            # differences negated, and its upper middle is the original's lower one);
            # select_kth left the m // 2 smaller ones in front: the lower is their largest
            lower = diff[0]
            for k in range(1, m // 2):
                lower = diff[k] if diff[k] > lower else lower
            med = 0.5 * (med + lower)
        out[i] = (med if med >= 0 else -med) * sqrt(m) / (1.2533 * sigma)
    return out_arr
