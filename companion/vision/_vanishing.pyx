"""Compiled loops of the layout-VP stage; the method is described in
:mod:`companion.vision.vanishing` (paper Fig. 2), which calls :func:`layout_vps` and
:func:`assign`.

Segments come in normalised camera coordinates (``(pixel − centre) / focal``), so a VP is
a 3-D direction and angles between VPs are angles in space.
"""

import numpy as np

from libc.math cimport asin, atan2, ceil, cos, exp, fmod, sin, sqrt

from companion.vision._geometry cimport (
    angle_between_deg,
    cross3,
    degrees,
    dot3,
    endpoint_weight,
    hypot,
    norm3,
    pixel_point,
    radians,
    segment_line,
    smallest_eigenvector,
    unit3,
    vp_angle_deg,
    vp_sin,
)



cdef double SAME_V3_DEG = 0.1
"""refined V3s closer than this complete into the same frame"""

cdef double LEVEL_MARGIN = 0.1
"""the frame of a level camera (V3 straight down, not fitted to any segment) replaces the
best fitted frame only with more than this share more support"""


cdef struct Params:
    double residual_px
    double max_angle_deg
    double sin_max  # sin(max_angle_deg), clipped to 1
    double vertical_max_tilt_deg
    int vertical_hypothesis_segments
    double vertical_max_camera_tilt_deg
    double histogram_bin_deg
    double histogram_sigma_deg
    double peak_min_share
    int max_horizontal_vps
    int vertical_alternatives
    double orthogonal_tol_deg
    double min_vp_separation_deg
    double orthogonal_sigma_deg


cdef Params _params(p):
    cdef Params q
    q.residual_px = p.residual_px
    q.max_angle_deg = p.max_angle_deg
    q.sin_max = 1.0 if p.max_angle_deg >= 90.0 else sin(radians(p.max_angle_deg))
    q.vertical_max_tilt_deg = p.vertical_max_tilt_deg
    q.vertical_hypothesis_segments = p.vertical_hypothesis_segments
    q.vertical_max_camera_tilt_deg = p.vertical_max_camera_tilt_deg
    q.histogram_bin_deg = p.histogram_bin_deg
    q.histogram_sigma_deg = p.histogram_sigma_deg
    q.peak_min_share = p.peak_min_share
    q.max_horizontal_vps = p.max_horizontal_vps
    q.vertical_alternatives = p.vertical_alternatives
    q.orthogonal_tol_deg = p.orthogonal_tol_deg
    q.min_vp_separation_deg = p.min_vp_separation_deg
    q.orthogonal_sigma_deg = p.orthogonal_sigma_deg
    return q


cdef inline double msac_score(const double* s, const double* v, double focal,
                              Params* p) noexcept nogil:
    """MSAC's truncated quadratic ``1 − r²`` (r: endpoint residual over ``residual_px``);
    0 unless the segment passes the inlier test (angle and residual).

    With ``u`` the segment, ``t`` the direction from its midpoint to ``v``, the angle's
    sine is ``|u × t| / (|u| |t|)`` and the endpoint residual ``|u × t| / (2 |t|)``: both
    tests and ``r²`` are ratios of squares, so no root, arcsine or second division."""
    cdef double ux = s[2] - s[0], uy = s[3] - s[1]
    cdef double tx = v[0] - v[2] * (0.5 * (s[0] + s[2]))
    cdef double ty = v[1] - v[2] * (0.5 * (s[1] + s[3]))
    cdef double t2 = tx * tx + ty * ty, u2 = ux * ux + uy * uy
    cdef double cross = ux * ty - uy * tx
    cdef double rr
    if u2 * t2 <= 1e-24:  # no direction to speak of: sin = 1
        rr = u2 * (focal / (2.0 * p.residual_px)) ** 2
        return 1.0 - rr if p.sin_max >= 1.0 and rr <= 1.0 else 0.0
    if cross * cross > p.sin_max * p.sin_max * u2 * t2:
        return 0.0
    rr = cross * cross * (focal / (2.0 * p.residual_px)) ** 2 / t2
    return 1.0 - rr if rr <= 1.0 else 0.0


cdef inline bint is_inlier(const double* s, const double* v, double focal,
                           Params* p) noexcept nogil:
    """The inlier test of :func:`msac_score`: angle and endpoint residual within bounds."""
    cdef double ux = s[2] - s[0], uy = s[3] - s[1]
    cdef double tx = v[0] - v[2] * (0.5 * (s[0] + s[2]))
    cdef double ty = v[1] - v[2] * (0.5 * (s[1] + s[3]))
    cdef double t2 = tx * tx + ty * ty, u2 = ux * ux + uy * uy
    cdef double cross = ux * ty - uy * tx
    cdef double k2 = (focal / (2.0 * p.residual_px)) ** 2
    if u2 * t2 <= 1e-24:
        return p.sin_max >= 1.0 and u2 * k2 <= 1.0
    return cross * cross <= p.sin_max * p.sin_max * u2 * t2 and cross * cross * k2 <= t2


cdef int scatter(double[:, ::1] ns, double[:, ::1] lines, const unsigned char* use,
                 double focal, Params* p, const double* vp, double* a,
                 double* msac_sum) noexcept nogil:
    """The fit's scatter matrix ``a`` = Σ w l lᵀ (row-major 3×3), w the MSAC score times
    the endpoint weight of each usable segment at ``vp``, so ``vᵀ a v`` is four times the
    MSAC-weighted sum of squared endpoint residuals (normalised units). Adds the MSAC
    scores to ``msac_sum``; returns how many segments carry weight."""
    cdef double w, m
    cdef Py_ssize_t i
    cdef int k, count = 0
    for k in range(9):
        a[k] = 0.0
    for i in range(ns.shape[0]):
        if not use[i]:
            continue
        m = msac_score(&ns[i, 0], vp, focal, p)
        if m == 0.0:
            continue
        w = m * endpoint_weight(&ns[i, 0], vp)
        if w == 0.0:
            continue
        count += 1
        msac_sum[0] += m
        for k in range(9):
            a[k] += w * lines[i, k // 3] * lines[i, k % 3]
    return count


cdef bint refine(double[:, ::1] ns, double[:, ::1] lines, const unsigned char* use,
                 double focal, Params* p, double* vp) noexcept nogil:
    """One least-squares step: the unit v minimising Σ w (l·v)² over the :func:`scatter`
    at ``vp``. False (``vp`` untouched) when fewer than two segments carry weight."""
    cdef double a[9]
    cdef double msac_sum = 0.0
    if scatter(ns, lines, use, focal, p, vp, a, &msac_sum) < 2:
        return False
    smallest_eigenvector(a, vp)
    return True


cdef tuple vertical_hypotheses(double[:, ::1] ns, double[:, ::1] lines, double[::1] lengths,
                               double focal, Params* p, unsigned char[::1] is_cand):
    """V3 hypotheses: pairs of the longest near-vertical segments (and straight down),
    each scored MSAC-style against the near-vertical segments (marked in ``is_cand``).
    Returns (hypotheses H×3, scores H), or None with fewer than two candidates."""
    cdef Py_ssize_t n = ns.shape[0], i, j, c, h
    cdef double min_cos = cos(radians(p.vertical_max_camera_tilt_deg))
    cdef Py_ssize_t[::1] cand = np.empty(n, np.intp)
    cdef Py_ssize_t ncand = 0, ntop, tmp
    for i in range(n):
        is_cand[i] = 0
        if degrees(atan2(abs(ns[i, 2] - ns[i, 0]), abs(ns[i, 3] - ns[i, 1]))) \
                <= p.vertical_max_tilt_deg:
            cand[ncand] = i
            ncand += 1
            is_cand[i] = 1
    if ncand < 2:
        return None
    # The longest candidates, by length then index (a stable sort).
    cdef Py_ssize_t[::1] top = np.empty(ncand, np.intp)
    for i in range(ncand):
        top[i] = cand[i]
        j = i
        while j > 0 and lengths[top[j]] > lengths[top[j - 1]]:
            tmp = top[j]
            top[j] = top[j - 1]
            top[j - 1] = tmp
            j -= 1
    ntop = min(ncand, <Py_ssize_t>p.vertical_hypothesis_segments)
    hyps_arr = np.empty((1 + ntop * (ntop - 1) // 2, 3))
    cdef double[:, ::1] hyps = hyps_arr
    cdef Py_ssize_t nh = 0
    cdef double hv[3]
    cdef double nrm
    hyps[0, 0] = 0.0
    hyps[0, 1] = 1.0
    hyps[0, 2] = 0.0
    nh = 1
    for i in range(ntop):
        for j in range(i + 1, ntop):
            cross3(&lines[top[i], 0], &lines[top[j], 0], hv)
            nrm = norm3(hv)
            if nrm <= 1e-12:
                continue
            hv[0] /= nrm
            hv[1] /= nrm
            hv[2] /= nrm
            # The camera is never pitched or rolled this far: V3 lies near the image's
            # y axis. Converging floor lines must not pass for verticals.
            if abs(hv[1]) < min_cos:
                continue
            hyps[nh, 0] = hv[0]
            hyps[nh, 1] = hv[1]
            hyps[nh, 2] = hv[2]
            nh += 1
    # Score every hypothesis against every candidate. With midpoint m and direction u of a
    # candidate and h = (x, y, w) a hypothesis, the direction from m to h is t = (x, y) − w·m;
    # u × t and |t|² are linear in products of h's entries, so each candidate's and each
    # hypothesis's factors are computed once, the tests compare squares, and the inner loop
    # runs over contiguous arrays without branches (the compiler vectorises it).
    factors = np.empty((8, ncand))
    cdef double[:, ::1] cf = factors
    scores_arr = np.zeros(nh)
    cdef double[::1] scores = scores_arr
    cdef double cl, mx, my, ux, uy, cross, t2, r2, score, ok
    cdef double h0, h1, h2, hh, hw0, hw1, ww
    cdef double sin2 = sin(radians(p.max_angle_deg)) ** 2
    cdef double sin2_f2 = sin2 / (focal * focal)
    cdef double scale = focal / (2.0 * p.residual_px)
    for c in range(ncand):
        i = cand[c]
        cl = lengths[i]
        mx = 0.5 * (ns[i, 0] + ns[i, 2])
        my = 0.5 * (ns[i, 1] + ns[i, 3])
        ux = (ns[i, 2] - ns[i, 0]) / cl
        uy = (ns[i, 3] - ns[i, 1]) / cl
        cf[0, c] = -uy
        cf[1, c] = ux
        cf[2, c] = uy * mx - ux * my
        cf[3, c] = mx
        cf[4, c] = my
        cf[5, c] = mx * mx + my * my
        cf[6, c] = (cl * scale) * (cl * scale)
        cf[7, c] = cl
    cdef const double* fa = &cf[0, 0]
    cdef const double* fb = &cf[1, 0]
    cdef const double* fc = &cf[2, 0]
    cdef const double* fx = &cf[3, 0]
    cdef const double* fy = &cf[4, 0]
    cdef const double* fm = &cf[5, 0]
    cdef const double* fr = &cf[6, 0]
    cdef const double* fl = &cf[7, 0]
    for h in range(nh):
        h0, h1, h2 = hyps[h, 0], hyps[h, 1], hyps[h, 2]
        hh = h0 * h0 + h1 * h1
        hw0 = 2.0 * h0 * h2
        hw1 = 2.0 * h1 * h2
        ww = h2 * h2
        score = 0.0
        for c in range(ncand):
            cross = h0 * fa[c] + h1 * fb[c] + h2 * fc[c]
            cross = cross * cross
            t2 = hh - hw0 * fx[c] - hw1 * fy[c] + ww * fm[c]
            # u has length 1/f here (pixels over pixel length, in normalised coordinates):
            # sin² = cross² f² / |t|², and the residual r = sin · l · scale ≤ 1.
            r2 = cross * fr[c]
            ok = (t2 > 1e-30) & (r2 <= t2) & (cross <= sin2_f2 * t2)
            score += ok * (fl[c] * (1.0 - r2 / (t2 if t2 > 1e-30 else 1.0)))
        scores[h] = score
    return hyps_arr, scores_arr


cdef Py_ssize_t vertical_inliers(double[:, ::1] ns, double focal, Params* p,
                                 const unsigned char* is_cand, const double* v3,
                                 unsigned char[::1] inl):
    """Mark in ``inl`` the near-vertical segments (``is_cand``) that point at ``v3``;
    returns their count."""
    cdef Py_ssize_t i, count = 0
    for i in range(ns.shape[0]):
        inl[i] = is_cand[i] and is_inlier(&ns[i, 0], v3, focal, p)
        count += inl[i]
    return count


cdef bint refine_vertical(double[:, ::1] ns, double[:, ::1] lines, double focal, Params* p,
                          const unsigned char* is_cand, double* best, unsigned char[::1] inl):
    """V3 from hypothesis ``best`` (in place): refined twice on the near-vertical segments,
    ``inl`` its inliers. False (``best`` the default, straight down, and no inliers) when
    fewer than two segments back it or it leans beyond the camera-tilt limit."""
    cdef Py_ssize_t n = ns.shape[0], i, k, count
    cdef double min_cos = cos(radians(p.vertical_max_camera_tilt_deg))
    for k in range(2):
        if not refine(ns, lines, is_cand, focal, p, best):
            break
    count = vertical_inliers(ns, focal, p, is_cand, best, inl)
    if count < 2 or abs(best[1]) / norm3(best) < min_cos:
        for i in range(n):
            inl[i] = 0
        best[0] = 0.0
        best[1] = 1.0
        best[2] = 0.0
        return False
    if best[1] < 0 or (best[1] == 0 and best[2] < 0):
        for k in range(3):
            best[k] = -best[k]
    return True


cdef int histogram_peaks(double[::1] theta, double[::1] weights, unsigned char[::1] use,
                         Params* p, double[::1] peaks):
    """Azimuths (degrees) of the peaks of the length-weighted, Gaussian-smoothed circular
    histogram of ``theta``, highest first, at most ``len(peaks)``; returns their count."""
    cdef int nbins = <int>(180.0 / p.histogram_bin_deg + 0.5)
    cdef int half = <int>ceil(3 * p.histogram_sigma_deg / p.histogram_bin_deg)
    # ``hist`` is circular: bin b is stored at b + half, with ``half`` bins of wrap-around
    # either side, so the smoothing loop needs no modulo.
    cdef double[::1] hist = np.zeros(nbins + 2 * half)
    cdef double[::1] smooth = np.zeros(nbins)
    cdef double[::1] kern = np.empty(2 * half + 1)
    cdef Py_ssize_t i, m, b
    cdef double ksum = 0.0, total = 0.0, x
    for i in range(theta.shape[0]):
        if use[i]:
            b = (<Py_ssize_t>(theta[i] / p.histogram_bin_deg)) % nbins
            hist[b + half] += weights[i]
    for m in range(half):
        hist[m] = hist[nbins + m]
        hist[nbins + half + m] = hist[half + m]
    for m in range(2 * half + 1):
        x = (m - half) * p.histogram_bin_deg / p.histogram_sigma_deg
        kern[m] = exp(-0.5 * x * x)
        ksum += kern[m]
    for i in range(nbins):
        x = 0.0
        for m in range(2 * half + 1):
            x += hist[i + m] * kern[m]
        smooth[i] = x
        total += x
    if total <= 0:
        return 0
    cdef double floor_ = p.peak_min_share * total / ksum
    cdef Py_ssize_t[::1] idx = np.empty(nbins, np.intp)
    cdef Py_ssize_t npk = 0, j, tmp
    for i in range(nbins):
        x = smooth[i]
        if x >= smooth[(i - 1 + nbins) % nbins] and x > smooth[(i + 1) % nbins] and x >= floor_:
            idx[npk] = i
            j = npk
            npk += 1
            while j > 0 and smooth[idx[j]] > smooth[idx[j - 1]]:
                tmp = idx[j]
                idx[j] = idx[j - 1]
                idx[j - 1] = tmp
                j -= 1
    npk = min(npk, peaks.shape[0])
    for i in range(npk):
        peaks[i] = (idx[i] + 0.5) * p.histogram_bin_deg
    return <int>npk


def layout_vps(segments_px, double cx, double cy, double focal, params):
    """The layout VPs of ``segments_px`` (N×4 pixels) for a pinhole with principal point
    ``(cx, cy)`` and ``focal`` pixels.

    V3 and the horizontal VPs are one Manhattan frame: the best
    ``vertical_alternatives`` distinct V3 hypotheses, and straight down, are each
    completed with their horizontal VPs, and the frame with the most support (V3, V1 and
    V2 together) wins, so that two long oblique lines that happen to meet below the image
    do not pass for the vertical when the horizontal structure says otherwise. Straight
    down unrefined (a level camera) is completed too, and wins only by ``LEVEL_MARGIN``.
    The winner's V1 × V2 is completed as one more V3 hypothesis.

    Returns ``(vps 3×3, observed (v1, v2, v3), supports 3, others K×3, others_support K)``:
    rows V1 (LMVP), V2, V3 and the further horizontal VPs as unit homogeneous pixel points.
    """
    cdef Params p = _params(params)
    cdef double[:, ::1] s = np.ascontiguousarray(segments_px, dtype=float).reshape(-1, 4)
    cdef Py_ssize_t n = s.shape[0], i, k, j, h
    cdef double[:, ::1] ns = np.empty((n, 4))
    cdef double[:, ::1] lines = np.empty((n, 3))
    cdef double[::1] lengths = np.empty(n)
    for i in range(n):
        ns[i, 0] = (s[i, 0] - cx) / focal
        ns[i, 1] = (s[i, 1] - cy) / focal
        ns[i, 2] = (s[i, 2] - cx) / focal
        ns[i, 3] = (s[i, 3] - cy) / focal
        segment_line(ns[i, 0], ns[i, 1], ns[i, 2], ns[i, 3], &lines[i, 0])
        lengths[i] = hypot(s[i, 2] - s[i, 0], s[i, 3] - s[i, 1])

    cdef unsigned char[::1] is_cand = np.zeros(n, np.uint8)
    cdef unsigned char[::1] inl = np.zeros(n, np.uint8)
    cdef double v3[3]
    # At most 15 alternatives and straight down are tried; each refined V3, then straight
    # down as it is and the best frame's V1 × V2, is kept in ``refined``: two more.
    cdef double tried[16][3]
    cdef double refined[18][3]
    cdef int ntried = 0, nrefined = 0
    cdef bint default_done = False, seen_before
    cdef double[:, ::1] hv
    cdef bint ok
    scored = vertical_hypotheses(ns, lines, lengths, focal, &p, is_cand)
    best = None
    if scored is None:
        v3[0], v3[1], v3[2] = 0.0, 1.0, 0.0
        best = horizontal_frame(ns, lines, lengths, focal, &p, v3, False, inl)
    else:
        hyps, scores = scored
        hv = hyps
        # The best-scored distinct hypotheses, then straight down (hypothesis 0: a level
        # camera) if it is not one of them: the true verticals can be few and short where
        # long oblique lines meet below the image.
        alternatives = max(1, min(p.vertical_alternatives, 15))
        chosen = []
        for h in np.argsort(-scores, kind="stable").tolist():
            if len(chosen) == alternatives:
                break
            if new_direction(&hv[h, 0], tried, &ntried, p.min_vp_separation_deg):
                chosen.append(h)
        if new_direction(&hv[0, 0], tried, &ntried, p.min_vp_separation_deg):
            chosen.append(0)
        for h in chosen:
            for k in range(3):
                v3[k] = hv[h, k]
            ok = refine_vertical(ns, lines, focal, &p, &is_cand[0], v3, inl)
            # Distinct hypotheses often refine to the same V3 (the same inliers); their
            # frames would be the same frame, so each V3 is completed once.
            if ok:
                seen_before = not new_direction(v3, refined, &nrefined, SAME_V3_DEG)
            else:  # V3 the default, straight down, without inliers
                seen_before, default_done = default_done, True
            if seen_before:
                continue
            frame = horizontal_frame(ns, lines, lengths, focal, &p, v3, ok, inl)
            if best is None or frame[0] > best[0]:
                best = frame
        # Straight down as it is: a level camera, as a multicopter's nearly is. Refined,
        # straight down can be led away by the floor's lines toward V2: below V2 they look
        # vertical, point at it within the thresholds and outnumber a room's few short
        # vertical edges, and V3 drifts several degrees toward V2, taking the horizon with
        # it. Fitted to no segment, this frame must be clearly better supported to win.
        v3[0], v3[1], v3[2] = 0.0, 1.0, 0.0
        if not default_done and new_direction(v3, refined, &nrefined, SAME_V3_DEG):
            ok = vertical_inliers(ns, focal, &p, &is_cand[0], v3, inl) >= 2
            frame = horizontal_frame(ns, lines, lengths, focal, &p, v3, ok, inl)
            if best is None or frame[0] > (1.0 + LEVEL_MARGIN) * best[0]:
                best = frame
        # The horizontal VPs, resting on many long edges, fix V3 as the direction ⟂ both.
        # Where the true verticals are few and short, no pair of them may be among the
        # hypotheses above: below a camera pitched down, floor lines running toward V2
        # are near-vertical too and outscore them. So the best frame's V1 × V2 is tried.
        if best[2][0] and best[2][1]:
            hv = best[1]
            cross3(&hv[0, 0], &hv[1, 0], v3)
            if unit3(v3) > 0 and abs(v3[1]) >= cos(radians(p.vertical_max_camera_tilt_deg)) \
                    and refine_vertical(ns, lines, focal, &p, &is_cand[0], v3, inl) \
                    and new_direction(v3, refined, &nrefined, SAME_V3_DEG):
                frame = horizontal_frame(ns, lines, lengths, focal, &p, v3, True, inl)
                if frame[0] > best[0]:
                    best = frame
    _, dirs, observed, supports, other_dirs, other_support = best
    cdef double[:, ::1] d = dirs
    polish(ns, lines, focal, &p, d, observed, other_dirs)
    for i in range(3):
        pixel_point(focal, cx, cy, &d[i, 0], &d[i, 0])
    cdef double[:, ::1] o = other_dirs
    for i in range(o.shape[0]):
        pixel_point(focal, cx, cy, &o[i, 0], &o[i, 0])
    return dirs, observed, supports, other_dirs, other_support


cdef inline bint inferred_v2(const double* v3, const double* v1, double* out) noexcept nogil:
    """V2 when only V1 is seen: the unit direction ``v3 × v1``, at right angles to both,
    facing forward (``z ≥ 0``). False (and zero) when V1 and V3 are the same direction."""
    cross3(v3, v1, out)
    if unit3(out) <= 0:
        return False
    if out[2] < 0:
        out[0], out[1], out[2] = -out[0], -out[1], -out[2]
    return True


cdef void polish(double[:, ::1] ns, double[:, ::1] lines, double focal, Params* p,
                 double[:, ::1] d, tuple observed, double[:, ::1] others):
    """Refit each observed layout VP (rows of ``d``: V1, V2, V3) on the segments that
    point at it better than at any other VP found (layout or obstacle), in place.

    The earlier fits share segments: every segment within the thresholds of a VP weighs
    on it, so a nearby family of parallel edges (a road beside a building, a rotated
    obstacle) pulls a layout VP towards itself. Here each segment is given to one VP, the
    one it points at most closely (as :func:`assign` labels segments), and each VP is
    refined twice over its own, then under :func:`orthogonal_prior` when
    ``orthogonal_sigma_deg`` is set. An inferred V2 is completed again ⟂ V1, V3."""
    cdef Py_ssize_t n = ns.shape[0], i, k, j
    cdef Py_ssize_t nv = 3 + others.shape[0]
    cdef double[:, ::1] v = np.empty((nv, 3))
    cdef unsigned char[::1] usable = np.ones(nv, np.uint8)
    for k in range(3):
        usable[k] = observed[k]
        for j in range(3):
            v[k, j] = d[k, j]
    for k in range(others.shape[0]):
        for j in range(3):
            v[3 + k, j] = others[k, j]
    cdef unsigned char[:, ::1] own = np.zeros((3, max(n, 1)), np.uint8)
    cdef double s2
    cdef Py_ssize_t label
    for i in range(n):
        label = nearest_vp(ns, i, v, &usable[0], p.sin_max, p.residual_px / focal, &s2)
        if 0 <= label < 3:
            own[label, i] = 1
    cdef double pt[3]
    for k in range(3):
        if not observed[k]:
            continue
        for j in range(2):
            refine(ns, lines, &own[k, 0], focal, p, &d[k, 0])
    if p.orthogonal_sigma_deg > 0:
        orthogonal_prior(ns, lines, own, focal, p, d, observed, p.orthogonal_sigma_deg)
    for k in range(3):
        if observed[k] and dot3(&d[k, 0], &v[k, 0]) < 0:  # keep the first fit's signs
            for j in range(3):
                d[k, j] = -d[k, j]
    if observed[0] and not observed[1] and inferred_v2(&d[2, 0], &d[0, 0], pt):
        for j in range(3):
            d[1, j] = pt[j]


cdef void orthogonal_prior(double[:, ::1] ns, double[:, ::1] lines,
                           unsigned char[:, ::1] own, double focal, Params* p,
                           double[:, ::1] d, tuple observed, double sigma_deg):
    """Refit the observed layout VPs (rows of ``d``, unit directions, in place) on their own
    segments (``own``, 3×N) under a soft prior that they are orthogonal in space.

    Each VP minimises its endpoint residuals over their variance plus
    Σ_j (v·v_j)² / σ² over the other observed VPs: the MAP estimate when the room's three
    directions are orthogonal to within ``sigma_deg`` (σ). A VP its segments pin down
    stays where they put it; one they hardly constrain (a horizontal VP near infinity, a
    few short segments) leans to the orthogonal frame. The residual variance is pooled
    over the three VPs. Two sweeps of one VP at a time, each the smallest eigenvector of
    its scatter plus λ Σ v_j v_jᵀ. Not a hard constraint (an exact rotation fit): real
    rooms, lenses and principal points are not quite that orthogonal, and on YUD that fit
    did worse."""
    cdef double a[3][9]
    cdef double m[9]
    cdef double cost, msac_sum, lam, sigma = radians(sigma_deg)
    cdef int count[3]
    cdef int k, j, q, sweep, nobs = 0
    for k in range(3):
        nobs += 1 if observed[k] else 0
    if nobs < 2:
        return
    for sweep in range(2):
        cost = 0.0
        msac_sum = 0.0
        for k in range(3):
            count[k] = 0
            if observed[k]:
                count[k] = scatter(ns, lines, &own[k, 0], focal, p, &d[k, 0], a[k], &msac_sum)
                for j in range(3):
                    for q in range(3):
                        cost += d[k, j] * a[k][3 * j + q] * d[k, q]
        if msac_sum <= 0:
            return
        # vᵀ a v is 4 × Σ MSAC-weighted squared residuals: their variance is cost / (4 Σ m).
        lam = cost / msac_sum / (sigma * sigma)
        for k in range(3):
            if count[k] < 2:
                continue
            for q in range(9):
                m[q] = a[k][q]
            for j in range(3):
                if j != k and observed[j]:
                    for q in range(9):
                        m[q] += lam * d[j, q // 3] * d[j, q % 3]
            smallest_eigenvector(m, &d[k, 0])


cdef tuple horizontal_frame(double[:, ::1] ns, double[:, ::1] lines, double[::1] lengths,
                            double focal, Params* p, double* v3, bint v3_ok,
                            unsigned char[::1] v3_inl):
    """The horizontal VPs for vertical VP ``v3`` (its inliers ``v3_inl`` set aside), and
    the frame's support. Returns (support of V3, V1 and V2 together, directions 3×3 (V1,
    V2, V3), observed (v1, v2, v3), supports 3 (V1, V2 MSAC-weighted; V3 inlier length),
    other directions K×3, their supports K)."""
    cdef Py_ssize_t n = ns.shape[0], i, k, j, ci
    # Horizontal VPs: each non-vertical line crosses the horizon at the azimuth θ of the
    # direction it would have if it were a horizontal edge.
    cdef double d3[3]
    cdef double e1[3]
    cdef double e2[3]
    cdef double pt[3]
    for k in range(3):
        d3[k] = v3[k]
    unit3(d3)
    e1[0] = 1.0 - d3[0] * d3[0]
    e1[1] = -d3[0] * d3[1]
    e1[2] = -d3[0] * d3[2]
    unit3(e1)
    cross3(e1, d3, e2)
    if e2[2] < 0:
        for k in range(3):
            e2[k] = -e2[k]
    cdef double[::1] theta = np.empty(n)
    cdef unsigned char[::1] use = np.zeros(n, np.uint8)
    cdef unsigned char[::1] rest = np.zeros(n, np.uint8)
    for i in range(n):
        rest[i] = not v3_inl[i]
        cross3(&lines[i, 0], v3, pt)
        theta[i] = fmod(degrees(atan2(dot3(pt, e1), dot3(pt, e2))), 180.0)
        if theta[i] < 0:
            theta[i] += 180.0
        use[i] = rest[i] and norm3(pt) > 1e-9
    cdef double[::1] peaks = np.empty(2 * p.max_horizontal_vps)
    cdef int npk = histogram_peaks(theta, lengths, use, p, peaks)

    # Peaks in order of height, each refined (twice) without the horizon constraint and
    # scored; kept when supported, distinct from those kept, and not the vertical VP.
    cdef double[:, ::1] pv = np.empty((max(npk, 1), 3))
    cdef double t, support
    cands = []
    for k in range(npk):
        t = radians(peaks[k])
        for j in range(3):
            pv[k, j] = sin(t) * e1[j] + cos(t) * e2[j]
        for j in range(2):
            refine(ns, lines, &rest[0], focal, p, &pv[k, 0])
        support = 0.0
        for i in range(n):
            if rest[i]:
                support += lengths[i] * msac_score(&ns[i, 0], &pv[k, 0], focal, p)
        if support <= 0:
            continue
        if pv[k, 2] < 0:
            for j in range(3):
                pv[k, j] = -pv[k, j]
        duplicate = False
        for c, _ in cands:
            ci = c
            if angle_between_deg(&pv[k, 0], &pv[ci, 0]) < p.min_vp_separation_deg:
                duplicate = True
                break
        if duplicate:
            continue
        if angle_between_deg(&pv[k, 0], v3) < 45.0:
            continue
        cands.append((k, support))
        if len(cands) >= p.max_horizontal_vps:
            break

    dirs = np.empty((3, 3))
    cdef double[:, ::1] d = dirs
    for j in range(3):
        d[2, j] = v3[j]
    observed_v1 = observed_v2 = False
    s1 = s2 = 0.0
    others = []
    if not cands:
        for j in range(3):  # azimuths 90° and 0°: image right and forward
            d[0, j] = e1[j] * sin(radians(90.0)) + e2[j] * cos(radians(90.0))
            d[1, j] = e2[j]
    else:
        first, second, v2_seen, others = _choose_layout(cands, pv, d3, p)
        k = first[0]
        for j in range(3):
            d[0, j] = pv[k, j]
        s1 = first[1]
        observed_v1 = True
        observed_v2 = v2_seen
        if v2_seen:
            k = second[0]
            for j in range(3):
                d[1, j] = pv[k, j]
            s2 = second[1]
        else:
            inferred_v2(d3, &pv[first[0], 0], pt)
            for j in range(3):
                d[1, j] = pt[j]
    v3_length = v3_score = 0.0
    for i in range(n):
        if v3_inl[i]:
            v3_length += lengths[i]
            v3_score += lengths[i] * msac_score(&ns[i, 0], v3, focal, p)
    other_dirs = np.array([[pv[k, 0], pv[k, 1], pv[k, 2]] for k, _ in others]).reshape(-1, 3)
    return (v3_score + s1 + s2, dirs, (observed_v1, observed_v2, bool(v3_ok)),
            np.array([s1, s2, v3_length]), other_dirs,
            np.array([w for _, w in others], dtype=float))


cdef bint new_direction(const double* d, double (*seen)[3], int* nseen,
                        double min_deg) noexcept nogil:
    """Whether the unit direction ``d`` is at least ``min_deg`` from every direction in
    ``seen``; if so it is added to them (the caller's array has room for it)."""
    cdef int t
    for t in range(nseen[0]):
        if angle_between_deg(d, seen[t]) < min_deg:
            return False
    for t in range(3):
        seen[nseen[0]][t] = d[t]
    nseen[0] += 1
    return True


cdef _choose_layout(list cands, double[:, ::1] pv, double* d3, Params* p):
    """Best-supported (near-)orthogonal pair of horizontal VPs; the rest are 'others'.
    Returns (V1 (row, support), V2 (row, support), whether V2 was seen, others).

    A pair's support is discounted for its departure ``dev`` from a right angle as MSAC
    discounts a residual, by ``1 − (dev / orthogonal_tol_deg)²``: of two pairs with
    about the same support (one axis seen as two nearby peaks) the more orthogonal wins,
    and the discount reaches zero at the tolerance, where a pair is refused."""
    cdef Py_ssize_t i, j, a, b, top = 0
    cdef double best_score = -1.0, best_support = -1.0, dev, score
    best = None
    for i in range(len(cands)):
        for j in range(i + 1, len(cands)):
            a, b = cands[i][0], cands[j][0]
            dev = abs(90.0 - angle_between_deg(&pv[a, 0], &pv[b, 0]))
            if dev > p.orthogonal_tol_deg:
                continue
            score = cands[i][1] + cands[j][1]
            if p.orthogonal_tol_deg > 0:
                score *= 1.0 - (dev / p.orthogonal_tol_deg) ** 2
            if score > best_score:
                best, best_score = (i, j), score
                best_support = cands[i][1] + cands[j][1]
    for i in range(1, len(cands)):
        if cands[i][1] > cands[top][1]:
            top = i
    if best is None or cands[top][1] > best_support:
        # Only one axis seen well: V2 is inferred ⟂ V1 on the horizon.
        return cands[top], None, False, [c for k, c in enumerate(cands) if k != top]
    i, j = best
    first, second = (i, j) if cands[i][1] >= cands[j][1] else (j, i)
    return cands[first], cands[second], True, [c for k, c in enumerate(cands) if k not in best]


cdef inline Py_ssize_t nearest_vp(double[:, ::1] s, Py_ssize_t i, double[:, ::1] v,
                                  const unsigned char* usable, double sin_max,
                                  double residual, double* best_s2) noexcept nogil:
    """The row of ``v`` (K×3 homogeneous points; only rows with ``usable[k]`` unless it is
    NULL) that segment ``s[i]`` points at most closely, among those within both thresholds:
    the angle between the segment and the direction from its midpoint to the point
    (``sin ≤ sin_max``), and how far its ends stray from that line (``≤ residual``, in the
    segment's units). −1 when none passes; ``best_s2`` is then 2, else the sin² of the
    angle."""
    cdef double ux = s[i, 2] - s[i, 0], uy = s[i, 3] - s[i, 1]
    cdef double u2 = ux * ux + uy * uy
    cdef double tx, ty, t2, cross, s2
    cdef Py_ssize_t k, label = -1
    best_s2[0] = 2.0
    for k in range(v.shape[0]):
        if usable != NULL and not usable[k]:
            continue
        tx = v[k, 0] - v[k, 2] * (0.5 * (s[i, 0] + s[i, 2]))
        ty = v[k, 1] - v[k, 2] * (0.5 * (s[i, 1] + s[i, 3]))
        t2 = tx * tx + ty * ty
        cross = ux * ty - uy * tx
        # sin² of the angle; the endpoint residual is |sin| · length / 2.
        s2 = 1.0 if u2 * t2 <= 1e-24 else min(cross * cross / (u2 * t2), 1.0)
        if s2 <= sin_max * sin_max and s2 * u2 <= 4.0 * residual * residual \
                and s2 < best_s2[0]:
            best_s2[0] = s2
            label = k
    return label


def assign(segments, vps, double max_angle_deg, double residual_px):
    """Each segment's label: the index of the most consistent of the K homogeneous points
    ``vps`` (K×3) that passes both thresholds (the angle between the segment and the
    direction from its midpoint to the point, and how far its ends stray from that line),
    or −1; and its angle to that point (to the first point when none passes). Inputs in
    one coordinate frame (pixels)."""
    cdef double[:, ::1] s = np.ascontiguousarray(segments, dtype=float).reshape(-1, 4)
    cdef double[:, ::1] v = np.ascontiguousarray(vps, dtype=float).reshape(-1, 3)
    cdef Py_ssize_t n = s.shape[0], i
    labels_arr = np.full(n, -1, dtype=np.int64)
    angles_arr = np.empty(n)
    cdef long long[::1] labels = labels_arr
    cdef double[::1] angles = angles_arr
    cdef double sin_max = 1.0 if max_angle_deg >= 90.0 else sin(radians(max_angle_deg))
    cdef double best_s2
    for i in range(n):
        labels[i] = nearest_vp(s, i, v, NULL, sin_max, residual_px, &best_s2)
        angles[i] = degrees(asin(sqrt(best_s2))) if labels[i] >= 0 else (
            vp_angle_deg(vp_sin(s[i, 0], s[i, 1], s[i, 2], s[i, 3], &v[0, 0]))
            if v.shape[0] else 90.0)
    return labels_arr, angles_arr
