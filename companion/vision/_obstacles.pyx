"""Compiled loops of the obstacle stage (eqs. 5–8); the method is described in
:mod:`companion.vision.obstacles`, which calls :func:`find`. The helpers keep the names of
the steps described there."""

import numpy as np

from libc.math cimport asin, fabs, sin, sqrt
from libc.stdlib cimport free, malloc, realloc

from companion.vision._geometry cimport (
    angle_between_deg,
    cross3,
    degrees,
    dot3,
    end_distance,
    endpoint_weight,
    hypot,
    pixel_point,
    radians,
    segment_line,
    smallest_eigenvector,
    unit3,
    vp_angle_deg,
    vp_sin,
)

cdef double INF = float("inf")
cdef double MIN_SIDE = sin(radians(20.0))  # a leg leaves its vertical edge at 20° or more
cdef double MIN_TOP_SPAN = 0.5  # a top's outermost hanging edges span half of it or more
cdef double FACE_CORE = 0.6  # a face's middle: its outline shrunk to this about its centre

# The rules an obstacle hypothesis comes from, in find_obstacles' order (a diagnosis: which
# rule read each detection and each false alarm).
cdef enum:
    CORNER_PAIR, SINGLE_CORNER, LEG_JUNCTIONS, TWO_FACES, EDGE_LEGS, HIDDEN_EDGE, ONE_FACE, \
        HANGING_FACE, STANDING_FACE
RULES = ("corner pair", "single corner", "leg junctions", "two faces", "edge legs",
         "hidden edge", "one face", "hanging face", "standing face")


cdef struct Params:
    double collinear_px
    double min_edge_px
    double horizon_tol_deg
    double orthogonal_tol_deg
    double single_corner_orthogonal_tol_deg
    double single_corner_noise_deg
    double single_face_tol_deg
    double room_right_angle_tol_deg  # single_face_tol_deg, or settled_focal_tol_deg
    double non_manhattan_min_deg
    double merge_deg
    double member_angle_deg
    double refit_slack_deg
    bint box_fit
    bint hidden_edge_corners
    double radius_px
    double leg_gap_frac
    double noise_px
    double edge_on_deg


# What every step needs of the layout: the camera, V3's direction, the horizon and the
# directions of V1 and V2.
cdef struct Frame:
    double f
    double cx
    double cy
    double d3[3]
    double v3[3]  # V3 as the layout gives it (homogeneous pixels), d3 its direction
    double horizon[3]
    double l1[3]
    double l2[3]


# An obstacle hypothesis: OVP directions, λ3 (eq. 8), its vertical edge's length, the
# Table-I corner it rests on (−1: none), further legs and corner points.
cdef struct Hypothesis:
    double d1[3]
    double d2[3]
    double lam3
    double edge
    Py_ssize_t corner
    Py_ssize_t legs[4]
    int nlegs
    double points[8]
    int npoints
    int rule  # which rule of find_obstacles made it: an index into RULES


cdef struct Hypotheses:
    Hypothesis* items
    Py_ssize_t count
    Py_ssize_t cap


cdef Hypothesis* new_hypothesis(Hypotheses* hs, int rule) except NULL:
    cdef Hypothesis* grown
    if hs.count == hs.cap:
        hs.cap = max(16, 2 * hs.cap)
        grown = <Hypothesis*>realloc(hs.items, hs.cap * sizeof(Hypothesis))
        if grown == NULL:
            raise MemoryError()
        hs.items = grown
    cdef Hypothesis* h = &hs.items[hs.count]
    hs.count += 1
    h.corner = -1
    h.nlegs = 0
    h.npoints = 0
    h.rule = rule
    return h


cdef inline void direction_of(Frame* fr, const double* p, double* out) noexcept nogil:
    """Unit 3-D direction ``K⁻¹ p`` of a homogeneous pixel point (zero stays zero)."""
    out[0] = p[0] - fr.cx * p[2]
    out[1] = p[1] - fr.cy * p[2]
    out[2] = fr.f * p[2]
    unit3(out)


cdef inline void set_v3(Frame* fr, const double* v3) noexcept nogil:
    """The frame's V3: ``v3`` (homogeneous pixels, as the layout gives it) and its
    direction; ``fr``'s focal length and principal point set first."""
    fr.v3[0], fr.v3[1], fr.v3[2] = v3[0], v3[1], v3[2]
    direction_of(fr, v3, fr.d3)


cdef inline bint intersect(const double* a, const double* b, double* out) noexcept nogil:
    """``a × b`` scaled to unit norm; False (and zero) when the two are the same."""
    cross3(a, b, out)
    return unit3(out) > 0


cdef inline bint at_border(Frame* fr, double x, double y, double margin) noexcept nogil:
    """Whether the pixel (x, y) is within ``margin`` of the frame's border (the principal
    point is the frame's centre, so the frame is 2 cx + 1 by 2 cy + 1 pixels)."""
    return x <= margin or y <= margin or x >= 2 * fr.cx - margin or y >= 2 * fr.cy - margin


cdef inline double below_horizon(Frame* fr, double x, double y) noexcept nogil:
    """Signed distance in pixels of (x, y) from the horizon, positive below it (image y
    grows downward)."""
    cdef double d = fr.horizon[0] * x + fr.horizon[1] * y + fr.horizon[2]
    return d if fr.horizon[1] > 0 else -d


cdef inline bint at_top(Frame* fr, double x, double y, double fx, double fy) noexcept nogil:
    """Whether a corner at (x, y) whose vertical edge runs to (fx, fy) is at the edge's top:
    the far end lies at least as far below the horizon (on a vertical line, the lower
    point in the world is the farther below it)."""
    return below_horizon(fr, fx, fy) >= below_horizon(fr, x, y)


cdef inline double horizon_error(Frame* fr, const double* d) noexcept nogil:
    """How far a direction is from horizontal (⟂ V3), degrees."""
    return fabs(90.0 - angle_between_deg(d, fr.d3))


cdef inline void ovp_error(Frame* fr, const double* d1, const double* d2,
                           double* horizon, double* ortho) noexcept nogil:
    """λ3 (eq. 8) parts: how far O1, O2 are from horizontal, and from orthogonal."""
    cdef double a = horizon_error(fr, d1), b = horizon_error(fr, d2)
    horizon[0] = a if a > b else b
    ortho[0] = fabs(90.0 - angle_between_deg(d1, d2))


cdef inline double bearing_gap_deg(Frame* fr, double x, double y, const double* d) noexcept nogil:
    """Angle in the horizontal plane between the ray to pixel (x, y) and the direction
    ``d``, in [0°, 90°]: 0 when a face along ``d`` through that point is seen edge-on, its
    edges on the point's own line through V3. The per-corner measure of
    :func:`companion.vision.obstacles.edge_on_angle_deg`."""
    cdef double r[3]
    cdef double h[3]
    cdef double kr, kh
    cdef Py_ssize_t i
    r[0], r[1], r[2] = x - fr.cx, y - fr.cy, fr.f
    kr, kh = dot3(r, fr.d3), dot3(d, fr.d3)
    for i in range(3):
        r[i] -= kr * fr.d3[i]
        h[i] = d[i] - kh * fr.d3[i]
    if unit3(r) == 0 or unit3(h) == 0:
        return 90.0
    return angle_between_deg(r, h)


cdef inline bint off_layout(Frame* fr, Params* p, const double* d) noexcept nogil:
    """At least ``non_manhattan_min_deg`` from V1 and from V2."""
    return (angle_between_deg(d, fr.l1) >= p.non_manhattan_min_deg
            and angle_between_deg(d, fr.l2) >= p.non_manhattan_min_deg)


cdef inline bint room_vouches_for_focal(Frame* fr, Params* p) noexcept nogil:
    """Whether the room's V1 and V2 are at a right angle within ``single_face_tol_deg``
    (``settled_focal_tol_deg`` under a video's settled focal length) under the focal
    length: a face's other OVP taken at a right angle through it is then trusted (a wrong
    focal length shows there)."""
    return fabs(90.0 - angle_between_deg(fr.l1, fr.l2)) <= p.room_right_angle_tol_deg


cdef inline bint box_ovps(Frame* fr, Params* p, const double* d1, const double* d2,
                          double* lam3) noexcept nogil:
    """Eq. 8 for the two OVP directions of one box: both within ``horizon_tol_deg`` of
    horizontal, at a right angle within ``orthogonal_tol_deg``, both away from V1 and V2.
    When they pass, ``lam3`` is λ3: the larger of the horizon error and the orthogonality
    error scaled to the horizon's tolerance."""
    cdef double hor, ortho, lam
    ovp_error(fr, d1, d2, &hor, &ortho)
    if hor > p.horizon_tol_deg or ortho > p.orthogonal_tol_deg:
        return False
    if not (off_layout(fr, p, d1) and off_layout(fr, p, d2)):
        return False
    lam = ortho * p.horizon_tol_deg / p.orthogonal_tol_deg
    lam3[0] = hor if hor > lam else lam
    return True


cdef inline void set_ovps(Hypothesis* h, const double* d1, const double* d2, double lam3,
                          double edge) noexcept nogil:
    """A hypothesis's OVP directions, its λ3 and its vertical edge's length."""
    cdef int k
    for k in range(3):
        h.d1[k] = d1[k]
        h.d2[k] = d2[k]
    h.lam3 = lam3
    h.edge = edge


cdef inline double signed_departure_deg(const double* a, const double* b) noexcept nogil:
    """Signed departure of unit directions ``a`` and ``b`` from a right angle, degrees."""
    cdef double c = dot3(a, b)
    return degrees(asin(-1.0 if c < -1.0 else (1.0 if c > 1.0 else c)))


cdef inline double right_angle_departure_deg(Frame* fr, double x1, double y1, double x2,
                                             double y2, const double* other) noexcept nogil:
    """Where the segment (x1, y1)–(x2, y2) crosses the horizon, as a direction: its signed
    departure from a right angle to ``other``, degrees (90 when it never crosses)."""
    cdef double line[3]
    cdef double o[3]
    cdef double d[3]
    segment_line(x1, y1, x2, y2, line)
    if not intersect(line, fr.horizon, o):
        return 90.0
    direction_of(fr, o, d)
    return signed_departure_deg(d, other)


cdef double crossing_noise_sq(Frame* fr, Params* p, double[:, ::1] s, Py_ssize_t k,
                              const double* other) noexcept nogil:
    """How far ``noise_px`` at each end of leg ``k`` (across the leg) moves the departure
    of its horizon crossing from a right angle to ``other``: the sum over its two ends of
    the squared change, degrees² (first order, by finite differences; INF for a leg of no
    length). A leg nearly along the horizon crosses it far away, where a pixel moves the
    crossing by degrees."""
    cdef double var = 0.0, e, nx, ny, ln, base
    cdef double q[4]
    cdef Py_ssize_t end
    nx, ny = s[k, 1] - s[k, 3], s[k, 2] - s[k, 0]
    ln = hypot(nx, ny)
    if ln <= 0:
        return INF
    nx, ny = nx / ln * p.noise_px, ny / ln * p.noise_px
    base = right_angle_departure_deg(fr, s[k, 0], s[k, 1], s[k, 2], s[k, 3], other)
    for end in range(2):
        q[0], q[1], q[2], q[3] = s[k, 0], s[k, 1], s[k, 2], s[k, 3]
        q[2 * end] += nx
        q[2 * end + 1] += ny
        e = right_angle_departure_deg(fr, q[0], q[1], q[2], q[3], other) - base
        var += e * e
    return var


cdef double right_angle_noise_deg(Frame* fr, Params* p, double[:, ::1] s, Py_ssize_t a,
                                  Py_ssize_t b, const double* d1,
                                  const double* d2) noexcept nogil:
    """How far ``noise_px`` at one end of leg ``a`` or ``b`` (across the leg) moves the
    right angle between their horizon crossings ``d1``, ``d2``: the root sum of squares over
    the four ends, degrees (:func:`crossing_noise_sq`)."""
    return sqrt(crossing_noise_sq(fr, p, s, a, d2) + crossing_noise_sq(fr, p, s, b, d1))


cdef bint horizon_ovps(Frame* fr, Params* p, double[:, ::1] s, double[:, ::1] lines,
                       Py_ssize_t a, Py_ssize_t b, double* d1, double* d2,
                       double* ortho) noexcept nogil:
    """OVPs where legs ``a`` and ``b`` cross the horizon, for a corner whose other end
    shows no leg: the horizon test then holds by construction, so only the tight
    ``single_corner_orthogonal_tol_deg`` and the distance from V1, V2 separate a box from
    chance. The right angle counts only where the legs' pixel noise could fail it: where
    ``noise_px`` at the legs' ends moves it by more than ``single_corner_noise_deg``
    (:func:`right_angle_noise_deg`), chance passes the test as readily as a box does
    (short legs, or one nearly along the horizon)."""
    cdef double o1[3]
    cdef double o2[3]
    cdef double hor
    cdef bint ok1 = intersect(&lines[a, 0], fr.horizon, o1)
    cdef bint ok2 = intersect(&lines[b, 0], fr.horizon, o2)
    direction_of(fr, o1, d1)
    direction_of(fr, o2, d2)
    ovp_error(fr, d1, d2, &hor, ortho)
    return (ok1 and ok2 and ortho[0] <= p.single_corner_orthogonal_tol_deg
            and off_layout(fr, p, d1) and off_layout(fr, p, d2)
            and right_angle_noise_deg(fr, p, s, a, b, d1, d2) <= p.single_corner_noise_deg)


cdef void far_ends(double[:, ::1] s, double[:, ::1] lines, double[:, ::1] pc,
                   long long[::1] cr, Py_ssize_t[::1] verticals, Params* p,
                   double[:, ::1] far, double[::1] reach, unsigned char[::1] usable) noexcept nogil:
    """The other end of each corner's vertical edge, following collinear V3 segments.

    A V3 segment is on the edge of ``L_r^g`` when λ1 (eq. 6), the largest distance of
    either segment's endpoints from the other's line, is within ``collinear_px``. The far
    end is the endpoint farthest from ``p_c`` on the side of the leg's midpoint (λ2 → π,
    eq. 7: the partner lies the other way from its own leg)."""
    cdef Py_ssize_t k, j, v, r, e
    cdef double ux, uy, nrm, lam1, d, along, best
    for k in range(pc.shape[0]):
        r = cr[k]
        ux = 0.5 * (s[r, 0] + s[r, 2]) - pc[k, 0]
        uy = 0.5 * (s[r, 1] + s[r, 3]) - pc[k, 1]
        nrm = hypot(ux, uy)
        usable[k] = nrm >= 1e-9
        if usable[k]:
            ux /= nrm
            uy /= nrm
        best = -INF
        for j in range(verticals.shape[0]):
            v = verticals[j]
            if v != r:
                lam1 = 0.0
                for e in range(2):
                    d = fabs(s[v, 2 * e] * lines[r, 0] + s[v, 2 * e + 1] * lines[r, 1]
                             + lines[r, 2])
                    lam1 = d if d > lam1 else lam1
                    d = fabs(s[r, 2 * e] * lines[v, 0] + s[r, 2 * e + 1] * lines[v, 1]
                             + lines[v, 2])
                    lam1 = d if d > lam1 else lam1
                if lam1 > p.collinear_px:
                    continue
            for e in range(2):
                along = (s[v, 2 * e] - pc[k, 0]) * ux + (s[v, 2 * e + 1] - pc[k, 1]) * uy
                best = along if along > best else best
        reach[k] = best
        usable[k] = usable[k] and best >= p.min_edge_px
        far[k, 0] = pc[k, 0] + (best if usable[k] else 0.0) * ux
        far[k, 1] = pc[k, 1] + (best if usable[k] else 0.0) * uy


cdef Py_ssize_t partner_legs(double[:, ::1] s, double[:, ::1] lines, double px, double py,
                             double ex, double ey, double edge, Py_ssize_t leg_s,
                             Py_ssize_t leg_n, Py_ssize_t[::1] free_idx, Params* p,
                             Py_ssize_t* out) noexcept nogil:
    """The free segments that are legs of C_h at the far end (ex, ey) of the edge from
    ``p_c`` = (px, py): a leg's line must cross the vertical line within
    ``radius_px + leg_gap_frac · edge`` of the far end, on the far half of the edge, and
    the leg must end within ``radius_px`` of that crossing; C_g's own legs are not C_h's.
    A leg leaves the edge at 20° or more: a piece of the vertical edge itself that missed
    the V3 label crosses the edge's line everywhere, and met with a leg of C_g it would put
    an OVP at C_g itself. Writes them to ``out`` in order; returns their count."""
    cdef double vline[3]
    cdef double q[3]
    cdef double qx, qy, ax = (ex - px) / edge, ay = (ey - py) / edge
    cdef Py_ssize_t j, f, count = 0
    segment_line(px, py, ex, ey, vline)
    for j in range(free_idx.shape[0]):
        f = free_idx[j]
        if f == leg_s or f == leg_n:
            continue
        if fabs(_side(s, f, ex, ey, ax, ay)) < MIN_SIDE:
            continue
        intersect(&lines[f, 0], vline, q)
        if fabs(q[2]) < 1e-12:
            continue
        qx = q[0] / q[2]
        qy = q[1] / q[2]
        if hypot(qx - ex, qy - ey) > p.radius_px + p.leg_gap_frac * edge:
            continue
        if (qx - px) * ax + (qy - py) * ay < 0.5 * edge:
            continue
        if end_distance(s, f, qx, qy) > p.radius_px:
            continue
        out[count] = f
        count += 1
    return count


cdef bint partner_ovps(Frame* fr, Params* p, double[:, ::1] lines, Py_ssize_t leg_s,
                       Py_ssize_t leg_n, const Py_ssize_t* hs, Py_ssize_t nh,
                       double* d1, double* d2, double* lam3) noexcept nogil:
    """The best OVPs of corner C_g's legs paired with the legs ``hs`` of its partner C_h.

    O1 = one leg of C_g × a partner leg ``h``; O2 = the other leg × a second partner leg
    ``h2``, or × the horizon when C_h shows only one leg. Two real partner legs beat one;
    then the smaller λ3 (eq. 8); then the first found. False when none is consistent."""
    cdef Py_ssize_t i, j, a, g1, g2, h, h2
    cdef double o1[3]
    cdef double o2[3]
    cdef double e1[3]
    cdef double e2[3]
    cdef double lam
    cdef bint found = False, found_real = False, ok1, ok2
    for i in range(nh):
        h = hs[i]
        for a in range(2):
            g1 = leg_s if a == 0 else leg_n
            g2 = leg_n if a == 0 else leg_s
            for j in range(-1, nh):
                h2 = -1 if j < 0 else hs[j]
                if h2 == h:
                    continue
                if found_real and h2 < 0:
                    continue
                ok1 = intersect(&lines[g1, 0], &lines[h, 0], o1)
                if h2 < 0:
                    ok2 = intersect(&lines[g2, 0], fr.horizon, o2)
                else:
                    ok2 = intersect(&lines[g2, 0], &lines[h2, 0], o2)
                if not (ok1 and ok2):
                    continue
                direction_of(fr, o1, e1)
                direction_of(fr, o2, e2)
                if not box_ovps(fr, p, e1, e2, &lam):
                    continue
                if found and (found_real or h2 < 0) and lam >= lam3[0]:
                    continue
                found = True
                found_real = h2 >= 0
                lam3[0] = lam
                d1[0], d1[1], d1[2] = e1[0], e1[1], e1[2]
                d2[0], d2[1], d2[2] = e2[0], e2[1], e2[2]
    return found


cdef inline void chain_axis(double[:, ::1] s, Py_ssize_t base, double* ox, double* oy,
                            double* axx, double* axy) noexcept:
    """The line a chain is measured along: segment ``base``'s first endpoint and its unit
    direction."""
    cdef double nrm
    ox[0], oy[0] = s[base, 0], s[base, 1]
    axx[0], axy[0] = s[base, 2] - ox[0], s[base, 3] - oy[0]
    nrm = hypot(axx[0], axy[0])
    nrm = nrm if nrm > 1e-9 else 1e-9
    axx[0] /= nrm
    axy[0] /= nrm


cdef list edge_chains(double[:, ::1] s, double[::1] lengths, double[:, ::1] lines,
                      Py_ssize_t[::1] verticals, Params* p):
    """Edges: the segments ``verticals`` (V3's, or the free legs) joined with collinear
    ones among them (λ1, eq. 6) across small gaps, as the detector breaks one edge where
    its background changes. Returns a list of (x_a, y_a, x_b, y_b, length, base), the two
    extreme endpoints, which lie on the line of ``base``, the longest member joined (whose
    direction is the most accurate; a collinear segment beyond the gaps is another
    thing's edge, and its direction is not this edge's)."""
    cdef Py_ssize_t nv = verticals.shape[0], i, j, e, k, vi, vj, m, base
    chains = []
    if nv == 0:
        return chains
    # Distance of the shorter segment's endpoints from the longer one's line: a short
    # piece's own direction is too noisy to extrapolate along a long edge.
    cdef unsigned char[:, ::1] collinear = np.zeros((nv, nv), np.uint8)
    cdef Py_ssize_t[::1] members_count = np.zeros(nv, np.intp)
    cdef double d, dist, lo, hi, gap, ox, oy, axx, axy, ta, tb
    for i in range(nv):
        for j in range(nv):
            if i == j:
                collinear[i, j] = 1
                continue
            vi, vj = verticals[i], verticals[j]
            if lengths[vi] < lengths[vj]:
                vi, vj = vj, vi
            dist = 0.0
            for e in range(2):
                d = fabs(lines[vi, 0] * s[vj, 2 * e] + lines[vi, 1] * s[vj, 2 * e + 1]
                         + lines[vi, 2])
                dist = d if d > dist else dist
            collinear[i, j] = dist <= p.collinear_px
    for i in range(nv):
        for j in range(nv):
            members_count[i] += collinear[i, j]
    processed = []
    for i in range(nv):
        vi = verticals[i]
        if members_count[i] == 1:  # most vertical segments: the chain is the segment itself
            if lengths[vi] >= 2 * p.min_edge_px:
                chains.append((s[vi, 0], s[vi, 1], s[vi, 2], s[vi, 3], lengths[vi], vi))
            continue
        # One chain per distinct set of collinear members, grown from its first segment.
        duplicate = False
        for k in processed:
            for j in range(nv):
                if collinear[i, j] != collinear[<Py_ssize_t>k, j]:
                    break
            else:
                duplicate = True
                break
        if duplicate:
            continue
        processed.append(i)
        # Measure along the longest member: its direction is the most accurate.
        base = vi
        for j in range(nv):
            if collinear[i, j] and j != i and lengths[verticals[j]] > lengths[base]:
                base = verticals[j]
        chain_axis(s, base, &ox, &oy, &axx, &axy)
        spans = []
        for j in range(nv):
            if collinear[i, j]:
                vj = verticals[j]
                ta = (s[vj, 0] - ox) * axx + (s[vj, 1] - oy) * axy
                tb = (s[vj, 2] - ox) * axx + (s[vj, 3] - oy) * axy
                spans.append((min(ta, tb), max(ta, tb), vj))
                if j == i:
                    lo, hi = min(ta, tb), max(ta, tb)
        spans.sort()
        joined = [vi]
        for a, b, vj in spans + spans[::-1]:
            gap = p.radius_px + p.leg_gap_frac * (hi - lo)
            if a <= hi + gap and b >= lo - gap:
                lo, hi = min(lo, a), max(hi, b)
                joined.append(vj)
        m = vi  # the longest member joined: the chain's line, measured along it again
        for vj in joined:
            m = vj if lengths[vj] > lengths[m] else m
        if m != base:
            base = m
            chain_axis(s, base, &ox, &oy, &axx, &axy)
            lo, hi = INF, -INF
            for vj in joined:
                for e in range(2):
                    ta = (s[vj, 2 * e] - ox) * axx + (s[vj, 2 * e + 1] - oy) * axy
                    lo, hi = min(lo, ta), max(hi, ta)
        if hi - lo >= 2 * p.min_edge_px:
            chains.append((ox + lo * axx, oy + lo * axy, ox + hi * axx, oy + hi * axy, hi - lo,
                           base))
    return chains


cdef inline bint leaves_end(double[:, ::1] s, double[::1] lengths, Py_ssize_t f, double ex,
                            double ey, double axx, double axy, Params* p,
                            double* side) noexcept:
    """Whether segment ``f`` is a leg of a vertical edge (direction (axx, axy)) at its end
    (ex, ey): at least ``min_edge_px`` long, an endpoint within ``radius_px`` of the end,
    leaving at 20° or more; ``side`` ← the sine of that angle (:func:`_side`)."""
    if lengths[f] < p.min_edge_px or end_distance(s, f, ex, ey) > p.radius_px:
        return False
    side[0] = _side(s, f, ex, ey, axx, axy)
    return fabs(side[0]) >= MIN_SIDE


cdef list edge_legs(Frame* fr, double[:, ::1] s, double[::1] lengths, list chains,
                    Py_ssize_t[::1] free_idx, Py_ssize_t[::1] room_idx, Params* p):
    """Vertical edges with the non-Manhattan legs that end at each of their two ends.

    Returns a list of (chain, legs_a, legs_b) with ``chain`` one of ``chains``
    (:func:`edge_chains`), or that chain grown at its foot (below); a leg is (segment
    index, side): the side (±1) of the edge it leaves toward. Legs are at least 20° off
    the edge (:func:`leaves_end`).

    An edge's foot, its lower end, may stop short of the junction of its legs by as much
    as a corner's vertical leg may (``radius_px + leg_gap_frac`` of its length): where a
    piece stands on the floor its own contact shadow dims the edge's last pixels. With no
    leg at the foot, a leg ending on the edge's line beyond it, within that gap, is met
    there, and the chain grown to it."""
    out = []
    if free_idx.shape[0] == 0 or not chains:
        return out
    cdef double ex, ey, axx, axy, side, ox, oy, t, reach
    cdef Py_ssize_t j, f, end, q
    for chain in chains:
        xa, ya, xb, yb, length, base = chain
        axx, axy = (xb - xa) / length, (yb - ya) / length
        ends = [(xa, ya), (xb, yb)]
        legs = ([], [])
        for end in range(2):
            ex, ey = ends[end]
            attached_legs(s, lengths, free_idx, ex, ey, axx, axy, p, legs[end])
            if legs[end] or below_horizon(fr, ex, ey) <= below_horizon(fr, ends[1 - end][0],
                                                                        ends[1 - end][1]):
                continue
            # A room edge leaving the foot: the edge stands there, on the room's floor line
            # (a door post, an aligned box), and what lies below is something else's.
            if attached_legs(s, lengths, room_idx, ex, ey, axx, axy, p, None):
                continue
            # The foot, with no leg: the nearest leg end on the edge's line below it.
            ox, oy = (-axx, -axy) if end == 0 else (axx, axy)
            reach = INF
            for j in range(free_idx.shape[0]):
                f = free_idx[j]
                for q in range(2):
                    t = (s[f, 2 * q] - ex) * ox + (s[f, 2 * q + 1] - ey) * oy
                    if p.radius_px < t <= p.radius_px + p.leg_gap_frac * length \
                            and t < reach and leaves_end(s, lengths, f, ex + t * ox,
                                                         ey + t * oy, axx, axy, p, &side):
                        reach = t
            if reach < INF:
                ex, ey = ex + reach * ox, ey + reach * oy
                ends[end] = (ex, ey)
                attached_legs(s, lengths, free_idx, ex, ey, axx, axy, p, legs[end])
                chain = (ends[0][0], ends[0][1], ends[1][0], ends[1][1], length + reach, base)
        if legs[0] or legs[1]:
            out.append((chain, legs[0], legs[1]))
    return out


cdef Py_ssize_t attached_legs(double[:, ::1] s, double[::1] lengths, Py_ssize_t[::1] among,
                              double ex, double ey, double axx, double axy, Params* p,
                              list out) except -1:
    """Appends to ``out`` the segments of ``among`` that leave the end (ex, ey) of a
    vertical edge along (axx, axy) (:func:`leaves_end`), as (segment index, side); how
    many. With ``out`` None, only whether any does (0 or 1)."""
    cdef double side
    cdef Py_ssize_t j, f, n = 0
    for j in range(among.shape[0]):
        f = among[j]
        if leaves_end(s, lengths, f, ex, ey, axx, axy, p, &side):
            if out is None:
                return 1
            out.append((f, 1.0 if side > 0 else -1.0))
            n += 1
    return n


cdef inline bint points_at_neither(double[:, ::1] s, Py_ssize_t k, const double* o1,
                                   const double* o2, double tol_deg) noexcept nogil:
    """Whether segment ``k`` points at neither of the pixel points ``o1``, ``o2`` within
    ``tol_deg``: a room edge that points at a box's OVP may be the box's own, labelled V1
    or V2 near the horizon."""
    return (vp_angle_deg(vp_sin(s[k, 0], s[k, 1], s[k, 2], s[k, 3], o1)) > tol_deg
            and vp_angle_deg(vp_sin(s[k, 0], s[k, 1], s[k, 2], s[k, 3], o2)) > tol_deg)


cdef bint room_leg_nearer(Params* p, double[:, ::1] s, double[::1] lengths,
                          Py_ssize_t[::1] manhattan_idx, tuple chain, Py_ssize_t leg_a,
                          Py_ssize_t leg_b, const double* o1, const double* o2) noexcept:
    """Whether at either end of the vertical edge ``chain`` (``leg_a`` leaving its first
    end, ``leg_b`` its second) a Manhattan segment (``manhattan_idx``: V1 or V2 beyond
    doubt) leaves toward the side of that end's leg and comes nearer the end than the leg
    does, by more than ``noise_px``, pointing at neither OVP (pixel points ``o1``, ``o2``)
    within ``member_angle_deg``. The end is then a door frame's or a picture's corner, and
    the leg a reflection, a shadow or a texture beside it. Near the horizon a box's own
    edge can be labelled V1 or V2, but it points at one of its OVPs."""
    cdef double axx = (chain[2] - chain[0]) / chain[4], axy = (chain[3] - chain[1]) / chain[4]
    cdef double ex, ey, reach, side
    cdef bint leg_right
    cdef Py_ssize_t j, k, leg
    cdef int end
    for end in range(2):
        leg = leg_a if end == 0 else leg_b
        ex, ey = chain[2 * end], chain[2 * end + 1]
        reach = end_distance(s, leg, ex, ey) - p.noise_px
        leg_right = _side(s, leg, ex, ey, axx, axy) > 0
        for j in range(manhattan_idx.shape[0]):
            k = manhattan_idx[j]
            if not leaves_end(s, lengths, k, ex, ey, axx, axy, p, &side) \
                    or (side > 0) != leg_right or end_distance(s, k, ex, ey) >= reach:
                continue
            if points_at_neither(s, k, o1, o2, p.member_angle_deg):
                return True
    return False


cdef void silhouette_halves(Frame* fr, Params* p, double[:, ::1] s, double[::1] lengths,
                            double[:, ::1] lines, list edges, Py_ssize_t[::1] manhattan_idx,
                            Hypotheses* halves) except *:
    """One OVP from each vertical edge whose two ends both show a leg on the same side.

    A box's outline edge (and any vertical edge with one face hidden) gives corners of two
    legs only: the vertical edge and one horizontal edge at each end. When the two
    horizontal edges bound one face they are parallel in space and meet at that face's
    OVP (eqs. 6–8 with one leg per corner), which must lie on the horizon and away from
    V1 and V2. A leg that a room edge beats to its end is not the edge's
    (:func:`room_leg_nearer`)."""
    cdef double o[3]
    cdef double d[3]
    cdef Py_ssize_t ka, kb
    cdef Hypothesis* h
    for chain, legs_a, legs_b in edges:
        for ka, sa in legs_a:
            for kb, sb in legs_b:
                if sa != sb:
                    continue
                if not intersect(&lines[ka, 0], &lines[kb, 0], o):
                    continue
                direction_of(fr, o, d)
                if horizon_error(fr, d) > p.horizon_tol_deg or not off_layout(fr, p, d):
                    continue
                if room_leg_nearer(p, s, lengths, manhattan_idx, chain, ka, kb, o, o):
                    continue
                h = new_hypothesis(halves, ONE_FACE)
                h.d1[0], h.d1[1], h.d1[2] = d[0], d[1], d[2]
                h.edge = chain[4]
                h.legs[0], h.legs[1] = ka, kb
                h.nlegs = 2
                h.points[0], h.points[1], h.points[2], h.points[3] = chain[:4]
                h.npoints = 2


cdef inline Py_ssize_t shared_leg(Hypothesis* a, Hypothesis* b) noexcept nogil:
    """The segment two silhouette halves both rest on, else −1."""
    cdef int i, j
    for i in range(a.nlegs):
        for j in range(b.nlegs):
            if a.legs[i] == b.legs[j]:
                return a.legs[i]
    return -1


cdef void pair_halves(Frame* fr, Params* p, double[:, ::1] s, double[:, ::1] lines,
                      Hypotheses* halves, Hypotheses* found) except *:
    """Two silhouette OVPs at a right angle (λ3, eq. 8) make an obstacle hypothesis.

    One edge bounds one face: a leg in both halves points at both OVPs, which only an edge
    along the horizon does (seen edge-on, from its own height). Such a leg meets every line
    on the horizon, so both halves passed the horizon test whatever their other legs were
    (a table's top seen at eye level, its front edge spanning two of its legs, with a
    shadow or a floor line at each foot). The OVPs are then where those two other legs
    cross the horizon, and they are held to a single corner's right-angle test
    (:func:`horizon_ovps`), as a box's bottom edges under a top at eye level pass it."""
    cdef Py_ssize_t i, j, k, shared, ka, kb
    cdef double lam
    cdef double d1[3]
    cdef double d2[3]
    cdef Hypothesis* a
    cdef Hypothesis* b
    cdef Hypothesis* h
    for i in range(halves.count):
        for j in range(i + 1, halves.count):
            a, b = &halves.items[i], &halves.items[j]
            shared = shared_leg(a, b)
            if shared >= 0:
                ka = a.legs[1] if a.legs[0] == shared else a.legs[0]
                kb = b.legs[1] if b.legs[0] == shared else b.legs[0]
                if ka == kb or not horizon_ovps(fr, p, s, lines, ka, kb, d1, d2, &lam):
                    continue
            else:
                # Each half is on the horizon and off V1, V2 already; eq. 8 adds the
                # right angle.
                if not box_ovps(fr, p, a.d1, b.d1, &lam):
                    continue
                for k in range(3):
                    d1[k], d2[k] = a.d1[k], b.d1[k]
            h = new_hypothesis(found, TWO_FACES)
            set_ovps(h, d1, d2, lam, a.edge if a.edge > b.edge else b.edge)
            h.nlegs = 4
            h.legs[0], h.legs[1], h.legs[2], h.legs[3] = a.legs[0], a.legs[1], b.legs[0], b.legs[1]
            h.npoints = 4
            for k in range(4):
                h.points[k] = a.points[k]
                h.points[4 + k] = b.points[k]


cdef inline bint same_edge(Hypothesis* a, Hypothesis* b) noexcept nogil:
    """Whether two silhouette halves rest on the same vertical edge (the same two ends)."""
    cdef int k
    for k in range(4):
        if a.points[k] != b.points[k]:
            return False
    return True


cdef void single_halves(Frame* fr, Params* p, Hypotheses* halves, Hypotheses* found) except *:
    """One silhouette OVP alone, the other face's OVP taken at a right angle to it on the
    horizon (``O2 ∝ O3 × O1`` in directions): a box of which one face shows its two
    horizontal edges and the other face none. With no second face to be orthogonal to,
    only the horizon test is left, so it is the tight ``single_face_tol_deg``; the right
    angle is taken through the focal length, so the room's V1 and V2 must be at one within
    the same tolerance (a wrong focal length shows there). A face has two outline edges, so
    three or more halves on one OVP are no face: a striped rug, whose stripes can pass for
    verticals, also has two parallel edges; nor is a half that shares a leg with a half on
    another OVP (:func:`pair_halves`)."""
    cdef Py_ssize_t i, j, k, agree
    cdef bint ambiguous
    cdef double d2[3]
    cdef Hypothesis* a
    cdef Hypothesis* h
    if not room_vouches_for_focal(fr, p):
        return
    for i in range(halves.count):
        a = &halves.items[i]
        if horizon_error(fr, a.d1) > p.single_face_tol_deg:
            continue
        # A face shows at most its two outline edges, each with one edge of the face at
        # either end: more halves on one OVP are repeated structure (the stripes of a rug
        # meeting its two edges), and halves of one vertical edge that disagree are legs
        # of more than one thing meeting there. Neither is a box. Nor is a half that shares
        # a leg with a half on another OVP: that leg lies along the horizon (pair_halves),
        # and with no second face there is no right angle to test instead.
        agree = 0
        ambiguous = False
        for j in range(halves.count):
            if angle_between_deg(a.d1, halves.items[j].d1) <= p.merge_deg:
                agree += 1
            elif same_edge(a, &halves.items[j]) or shared_leg(a, &halves.items[j]) >= 0:
                ambiguous = True
        if agree > 2 or ambiguous:
            continue
        cross3(fr.d3, a.d1, d2)
        if unit3(d2) <= 0:
            continue
        h = new_hypothesis(found, ONE_FACE)  # grows ``found``; ``a`` points into ``halves``
        set_ovps(h, a.d1, d2, horizon_error(fr, a.d1), a.edge)
        h.legs[0], h.legs[1] = a.legs[0], a.legs[1]
        h.nlegs = 2
        for k in range(4):
            h.points[k] = a.points[k]
        h.npoints = 2


cdef void edge_horizon_pairs(Frame* fr, Params* p, double[:, ::1] s, double[::1] lengths,
                             double[:, ::1] lines, list edges, Py_ssize_t[::1] manhattan_idx,
                             Hypotheses* found) except *:
    """A leg at each end of one vertical edge whose horizon crossings are orthogonal OVPs.

    The fallback for an edge whose two legs bound two different faces (a box seen from
    above its top, its faces too alike for the edge between them to show): each leg's OVP
    is where it crosses the horizon, as for a single corner. One leg must be at each end:
    two legs at one end may be a rug's corner touching a door frame. Per edge, its most
    orthogonal pair (the first on ties). The edge's other legs, up to four in all, go with
    it: one short leg's horizon crossing moves by degrees for a pixel of noise, and the
    box fit (:func:`obstacle`) rests each OVP on every leg that points at it. A leg that a
    room edge beats to its end is not the edge's (:func:`room_leg_nearer`)."""
    cdef double d1[3]
    cdef double d2[3]
    cdef double b1[3]
    cdef double b2[3]
    cdef double o1[3]
    cdef double o2[3]
    cdef double ortho, best
    cdef Py_ssize_t ka, kb, k
    cdef Hypothesis* h
    for chain, legs_a, legs_b in edges:
        if chain[4] < 2 * p.min_edge_px:
            continue
        best = INF
        for ka, _ in legs_a:
            for kb, _ in legs_b:
                if ka == kb:
                    continue
                if not horizon_ovps(fr, p, s, lines, ka, kb, d1, d2, &ortho) or ortho >= best:
                    continue
                pixel_point(fr.f, fr.cx, fr.cy, d1, o1)
                pixel_point(fr.f, fr.cx, fr.cy, d2, o2)
                if room_leg_nearer(p, s, lengths, manhattan_idx, chain, ka, kb, o1, o2):
                    continue
                best = ortho
                for k in range(3):
                    b1[k] = d1[k]
                    b2[k] = d2[k]
                best_a, best_b = ka, kb
        if best == INF:
            continue
        h = new_hypothesis(found, EDGE_LEGS)
        set_ovps(h, b1, b2, best, chain[4])
        h.legs[0], h.legs[1] = best_a, best_b
        h.nlegs = 2
        for k, _ in legs_a + legs_b:
            if h.nlegs < 4 and k != best_a and k != best_b:
                h.legs[h.nlegs] = k
                h.nlegs += 1
        h.points[0], h.points[1], h.points[2], h.points[3] = chain[:4]
        h.npoints = 2


cdef void junction_edge_pairs(Frame* fr, Params* p, double[:, ::1] s, double[:, ::1] lines,
                              double[::1] lengths, list edges, list junctions,
                              Py_ssize_t[::1] room_idx, Hypotheses* found) except *:
    """Two legs meeting at a junction where no vertical edge shows, one of them running on
    to a vertical edge at its far end: the near corner of a box whose two faces are lit
    alike, and the box's outline edge. Each leg's OVP is where it crosses the horizon, as
    for a single corner (``single_corner_orthogonal_tol_deg``).

    A flat thing on the floor beside a vertical edge looks the same, and is told apart by
    the edge: at the junction itself it may be a rug's corner touching a door frame (so it
    must be at the leg's far end); where a room edge (V1, V2, in ``room_idx``) leaves
    either of its ends, it is the edge of a Manhattan thing (a door frame, an aligned box)
    that a rug or a shadow only touches. An edge labelled V1 or V2 that points at one of
    the two OVPs is no such proof: near the horizon the box's own top edges are labelled
    so. At a junction below the unseen edge, its legs leave toward either side of it
    (:func:`foot_legs_apart`, the edge rising from the junction as the seen one rises from
    the leg's far end). The face read, between the seen edge and the junction, is opaque:
    a room edge seen in its middle (:func:`room_edge_inside`) is behind no face. Per
    junction, its first such pair."""
    cdef double d1[3]
    cdef double d2[3]
    cdef double o1[3]
    cdef double o2[3]
    cdef double ortho, ex, ey
    cdef Py_ssize_t a, b, leg, end, k
    cdef Hypothesis* h
    cdef double* face_ovp
    if not junctions or not edges:
        return
    # For each free leg, the vertical edges it leaves from: (chain, which end).
    attached = {}
    for chain, legs_a, legs_b in edges:
        for end, legs in enumerate((legs_a, legs_b)):
            for leg, _ in legs:
                attached.setdefault(leg, []).append((chain, end))
    for x, y, a, b in junctions:
        if not horizon_ovps(fr, p, s, lines, a, b, d1, d2, &ortho):
            continue
        # A leg seen edge-on runs along the junction's own line through V3, where the
        # unseen vertical edge would be: a line on the floor aimed at the camera's foot
        # (a rug's side) looks so, and the junction is then no proof of a box's corner.
        if bearing_gap_deg(fr, x, y, d1) < p.edge_on_deg \
                or bearing_gap_deg(fr, x, y, d2) < p.edge_on_deg:
            continue
        pixel_point(fr.f, fr.cx, fr.cy, d1, o1)
        pixel_point(fr.f, fr.cx, fr.cy, d2, o2)
        for leg in (a, b):
            if leg not in attached:
                continue
            for chain, end in attached[leg]:
                ex, ey = (chain[0], chain[1]) if end == 0 else (chain[2], chain[3])
                if hypot(ex - x, ey - y) <= 2 * p.radius_px:
                    continue  # the edge starts at the junction itself
                # The unseen edge rises from the junction as the seen one from the leg's
                # far end (or falls, at a top): a foot's legs leave it toward either side.
                if not foot_legs_apart(fr, s, x, y, x + chain[2 - 2 * end] - ex,
                                       y + chain[3 - 2 * end] - ey, a, b):
                    continue
                if room_edge_at(s, lengths, chain, room_idx, o1, o2, p):
                    continue
                face_ovp = o1  # the OVP of the face the leg bounds
                if leg == b:
                    face_ovp = o2
                if room_edge_inside(s, lengths, room_idx, x, y, ex, ey, chain[2 - 2 * end],
                                    chain[3 - 2 * end], face_ovp, fr.v3, p):
                    continue
                h = new_hypothesis(found, HIDDEN_EDGE)
                set_ovps(h, d1, d2, ortho, chain[4])
                h.legs[0], h.legs[1] = a, b
                h.nlegs = 2
                h.points[0], h.points[1] = x, y
                for k in range(4):
                    h.points[2 + k] = chain[k]
                h.npoints = 3
                break
            else:
                continue
            break


cdef bint room_edge_inside(double[:, ::1] s, double[::1] lengths, Py_ssize_t[::1] room_idx,
                           double jx, double jy, double nx, double ny, double fx, double fy,
                           const double* ovp, const double* v3_px, Params* p) noexcept:
    """Whether a room edge (``room_idx``, ``min_edge_px`` or longer) has its midpoint in
    the middle of a face: the face between a corner's unseen vertical edge at the junction
    (jx, jy) and the seen edge from (nx, ny), where the leg from the junction meets it, to
    (fx, fy); its edge through (fx, fy) runs toward the leg's OVP ``ovp`` (homogeneous
    pixels) to the unseen edge's line through V3 (``v3_px``, homogeneous). The outline
    shrunk to ``FACE_CORE`` about its centre keeps clear of the face's own edges, which
    near the horizon may be labelled V1 or V2. A face hides what stands behind it; a rug's
    side running to an aligned piece's leg is read as such a face with the floor's and the
    walls' lines showing in it."""
    cdef double pt[3]
    cdef double top[3]
    cdef double unseen[3]
    cdef double corner[3]
    cdef double qx[4]
    cdef double qy[4]
    cdef double mx, my, px, py, cross
    cdef int i, sign
    cdef Py_ssize_t j, k
    pt[0], pt[1], pt[2] = fx, fy, 1.0
    cross3(pt, ovp, top)
    pt[0], pt[1], pt[2] = jx, jy, 1.0
    cross3(pt, v3_px, unseen)
    if not intersect(top, unseen, corner) or fabs(corner[2]) < 1e-12:
        return False
    qx[0], qx[1], qx[2], qx[3] = jx, nx, fx, corner[0] / corner[2]
    qy[0], qy[1], qy[2], qy[3] = jy, ny, fy, corner[1] / corner[2]
    mx = (qx[0] + qx[1] + qx[2] + qx[3]) / 4
    my = (qy[0] + qy[1] + qy[2] + qy[3]) / 4
    for i in range(4):
        qx[i] = mx + FACE_CORE * (qx[i] - mx)
        qy[i] = my + FACE_CORE * (qy[i] - my)
    for j in range(room_idx.shape[0]):
        k = room_idx[j]
        if lengths[k] < p.min_edge_px:
            continue
        px, py = (s[k, 0] + s[k, 2]) / 2, (s[k, 1] + s[k, 3]) / 2
        sign = 0
        for i in range(4):
            cross = ((qx[(i + 1) % 4] - qx[i]) * (py - qy[i])
                     - (qy[(i + 1) % 4] - qy[i]) * (px - qx[i]))
            if cross == 0 or (sign != 0 and (cross > 0) != (sign > 0)):
                break
            sign = 1 if cross > 0 else -1
        else:
            return True
    return False


cdef bint room_edge_at(double[:, ::1] s, double[::1] lengths, tuple chain,
                       Py_ssize_t[::1] room_idx, const double* o1, const double* o2,
                       Params* p, bint both_ends=True):
    """Whether a room edge (``room_idx``) leaves either end of the vertical edge ``chain``
    (:func:`leaves_end`; with ``both_ends`` False only its second end, ``chain[2:4]``) and
    points at neither OVP ``o1``, ``o2`` within ``member_angle_deg``: near the horizon an
    edge of the box itself can be labelled V1 or V2, and it still points at one of the
    box's OVPs."""
    cdef double axx = (chain[2] - chain[0]) / chain[4], axy = (chain[3] - chain[1]) / chain[4]
    cdef double side
    cdef Py_ssize_t j, k, end
    for j in range(room_idx.shape[0]):
        k = room_idx[j]
        for end in range(0 if both_ends else 1, 2):
            if leaves_end(s, lengths, k, chain[2 * end], chain[2 * end + 1], axx, axy, p,
                          &side):
                break
        else:
            continue
        if points_at_neither(s, k, o1, o2, p.member_angle_deg):
            return True
    return False


cdef bint stands_short(Frame* fr, double[:, ::1] s, double[::1] lengths, Py_ssize_t r,
                       double px, double py, double ex, double ey, Py_ssize_t[::1] room_idx,
                       const double* o1, const double* o2, Params* p):
    """Whether the corner at (px, py) lies below its vertical edge, which rises to
    (ex, ey), and the edge's leg ``r`` ends more than ``radius_px`` above the corner, at a
    point a room edge leaves (:func:`room_edge_at`): the edge's own foot is there, on the
    room's floor line, and the corner below is something else's. At the corner itself the
    room edges a box hides end too, so only an end apart from it can tell. A corner at the
    top of its edge is not tested: under a table's top the room shows between the legs,
    and its edges leave a leg's head."""
    if at_top(fr, px, py, ex, ey):
        return False
    cdef double qx = s[r, 0], qy = s[r, 1]
    if (s[r, 2] - px) ** 2 + (s[r, 3] - py) ** 2 < (qx - px) ** 2 + (qy - py) ** 2:
        qx, qy = s[r, 2], s[r, 3]
    if hypot(qx - px, qy - py) <= p.radius_px:
        return False
    return room_edge_at(s, lengths, (ex, ey, qx, qy, hypot(ex - qx, ey - qy)), room_idx, o1,
                        o2, p, False)


cdef list leg_junctions(double[:, ::1] s, double[:, ::1] lines, double[::1] lengths,
                        Py_ssize_t[::1] free_idx, double min_leg_sin, Params* p):
    """Two obstacle legs whose ends meet at their intersection, at least
    ``asin(min_leg_sin)`` apart (a corner projection without its vertical leg, eq. 2).
    Returns a list of (x, y, leg a, leg b)."""
    cdef Py_ssize_t i, j, a, b
    cdef double q[3]
    cdef double x, y, d, r2 = p.radius_px * p.radius_px, sn
    out = []
    for i in range(free_idx.shape[0]):
        a = free_idx[i]
        if lengths[a] < p.min_edge_px:
            continue
        for j in range(i + 1, free_idx.shape[0]):
            b = free_idx[j]
            if lengths[b] < p.min_edge_px:
                continue
            d = min(min((s[a, 0] - s[b, 0]) ** 2 + (s[a, 1] - s[b, 1]) ** 2,
                        (s[a, 0] - s[b, 2]) ** 2 + (s[a, 1] - s[b, 3]) ** 2),
                    min((s[a, 2] - s[b, 0]) ** 2 + (s[a, 3] - s[b, 1]) ** 2,
                        (s[a, 2] - s[b, 2]) ** 2 + (s[a, 3] - s[b, 3]) ** 2))
            if d > r2:
                continue
            sn = abs((s[a, 2] - s[a, 0]) * (s[b, 3] - s[b, 1])
                     - (s[a, 3] - s[a, 1]) * (s[b, 2] - s[b, 0])) / (lengths[a] * lengths[b])
            if sn < min_leg_sin or not intersect(&lines[a, 0], &lines[b, 0], q) \
                    or abs(q[2]) < 1e-12:
                continue
            x, y = q[0] / q[2], q[1] / q[2]
            if end_distance(s, a, x, y) > p.radius_px or end_distance(s, b, x, y) > p.radius_px:
                continue
            out.append((x, y, a, b))
    return out


cdef void junction_pairs(Frame* fr, Params* p, double[:, ::1] s, double[:, ::1] lines,
                         list junctions, Hypotheses* found) except *:
    """Two leg junctions one above the other along V3: the top and bottom corners of a
    vertical edge the detector did not see (both faces alike), the paper's pair (eqs. 6–8)
    with L_r implied. At each junction one leg must leave toward each side of the edge;
    the two legs on a side bound one face, so they meet at its OVP, and the two OVPs
    must pass eq. 8 (horizon, orthogonality, away from V1 and V2)."""
    cdef Py_ssize_t i, j, k
    cdef double vline[3]
    cdef double ja[3]
    cdef double o1[3]
    cdef double o2[3]
    cdef double d1[3]
    cdef double d2[3]
    cdef double ex, ey, length, lam
    cdef Py_ssize_t legs_a[2]
    cdef Py_ssize_t legs_b[2]
    cdef Hypothesis* h
    for i in range(len(junctions)):
        xa, ya, a1, a2 = junctions[i]
        ja[0], ja[1], ja[2] = xa, ya, 1.0
        # The vertical line through this junction (toward V3), in pixel distances.
        cross3(ja, fr.v3, vline)
        length = hypot(vline[0], vline[1])
        if length <= 0:
            continue
        vline[0] /= length
        vline[1] /= length
        vline[2] /= length
        for j in range(i + 1, len(junctions)):
            xb, yb, b1, b2 = junctions[j]
            length = hypot(xb - xa, yb - ya)
            if length < 2 * p.min_edge_px \
                    or abs(vline[0] * xb + vline[1] * yb + vline[2]) > p.collinear_px:
                continue
            if len({a1, a2, b1, b2}) < 4:
                continue
            ex, ey = (xb - xa) / length, (yb - ya) / length
            if not (_split(s, a1, a2, xa, ya, ex, ey, MIN_SIDE, legs_a)
                    and _split(s, b1, b2, xb, yb, ex, ey, MIN_SIDE, legs_b)):
                continue
            if not (intersect(&lines[legs_a[0], 0], &lines[legs_b[0], 0], o1)
                    and intersect(&lines[legs_a[1], 0], &lines[legs_b[1], 0], o2)):
                continue
            direction_of(fr, o1, d1)
            direction_of(fr, o2, d2)
            if not box_ovps(fr, p, d1, d2, &lam):
                continue
            h = new_hypothesis(found, LEG_JUNCTIONS)
            set_ovps(h, d1, d2, lam, length)
            h.legs[0], h.legs[1], h.legs[2], h.legs[3] = legs_a[0], legs_b[0], legs_a[1], legs_b[1]
            h.nlegs = 4
            h.points[0], h.points[1], h.points[2], h.points[3] = xa, ya, xb, yb
            h.npoints = 2


cdef bint _split(double[:, ::1] s, Py_ssize_t a, Py_ssize_t b, double x, double y, double ex,
                 double ey, double min_side, Py_ssize_t* out) noexcept:
    """The two legs of a junction at (x, y) by the side of the edge (direction (ex, ey))
    they leave toward: ``out`` = (the −1 side's, the +1 side's). False unless one leaves
    toward each side, each at least ``asin(min_side)`` off the edge."""
    cdef double sa = _side(s, a, x, y, ex, ey), sb = _side(s, b, x, y, ex, ey)
    if abs(sa) < min_side or abs(sb) < min_side or (sa > 0) == (sb > 0):
        return False
    out[0], out[1] = (a, b) if sa < 0 else (b, a)
    return True


cdef inline bint foot_legs_apart(Frame* fr, double[:, ::1] s, double x, double y,
                                 double fx, double fy, Py_ssize_t a, Py_ssize_t b) noexcept:
    """Whether a corner at (x, y) whose vertical edge rises to (fx, fy) can be a box's foot:
    its legs ``a``, ``b`` leave toward opposite sides of the edge. At the foot of a convex
    box seen from above the floor, the two bottom edges in sight bound the two faces in
    sight, one on each side of the edge between them (the other face's bottom edge is
    behind the box). Two legs on one side at the foot are a flat thing's, a rug's corner
    or a shadow's, beside something vertical. A corner below its edge's far end is at the
    edge's foot; at the top, seen from above, a box's top face does put both legs on one
    side, so only the foot is tested. A leg along the edge itself (sine 0) counts with
    those of negative sine (:func:`_split` at any angle off the edge)."""
    cdef Py_ssize_t by_side[2]
    if at_top(fr, x, y, fx, fy):
        return True
    return _split(s, a, b, x, y, fx - x, fy - y, 0.0, by_side)


cdef inline double _side(double[:, ::1] s, Py_ssize_t i, double x, double y, double ex,
                         double ey) noexcept nogil:
    """Sine of the angle from the edge direction to segment ``i`` leaving (x, y) along it
    (its far end minus its near end)."""
    cdef double fx = s[i, 2] - s[i, 0], fy = s[i, 3] - s[i, 1]
    cdef double n = hypot(fx, fy)
    if (s[i, 0] - x) ** 2 + (s[i, 1] - y) ** 2 > (s[i, 2] - x) ** 2 + (s[i, 3] - y) ** 2:
        fx, fy = -fx, -fy
    return (ex * fy - ey * fx) / (n if n > 0 else 1.0)


cdef Py_ssize_t root(Py_ssize_t* parent, Py_ssize_t i) noexcept nogil:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


cdef list group_by_ovps(Hypotheses* found, double merge_deg):
    """Union-find over hypotheses whose OVP sets agree within ``merge_deg``; groups in
    order of their first member."""
    cdef Py_ssize_t n = found.count, i, j
    cdef Py_ssize_t* parent = <Py_ssize_t*>malloc(n * sizeof(Py_ssize_t))
    cdef Hypothesis* a
    cdef Hypothesis* b
    cdef double same, cross_
    for i in range(n):
        parent[i] = i
    for i in range(n):
        for j in range(i + 1, n):
            a, b = &found.items[i], &found.items[j]
            same = max(angle_between_deg(a.d1, b.d1), angle_between_deg(a.d2, b.d2))
            cross_ = max(angle_between_deg(a.d1, b.d2), angle_between_deg(a.d2, b.d1))
            if min(same, cross_) <= merge_deg:
                parent[root(parent, i)] = root(parent, j)
    groups = {}
    for i in range(n):
        groups.setdefault(root(parent, i), []).append(i)
    free(parent)
    return list(groups.values())


cdef void refit_ovp(double[:, ::1] s, double[:, ::1] lines, list legs, const double* ref_px,
                    double max_angle_deg, double* out) noexcept:
    """An OVP refit on the legs pointing at ``ref_px`` within ``max_angle_deg``: least
    squares on endpoint residuals, as for the layout VPs (two passes); ``ref_px`` itself
    when fewer than two legs point at it."""
    cdef double a[9]
    cdef double vp[3]
    cdef double w
    cdef Py_ssize_t it, k, i
    mine = []
    for i in legs:
        if vp_angle_deg(vp_sin(s[i, 0], s[i, 1], s[i, 2], s[i, 3], ref_px)) <= max_angle_deg:
            mine.append(i)
    out[0], out[1], out[2] = ref_px[0], ref_px[1], ref_px[2]
    if len(mine) < 2:
        return
    vp[0], vp[1], vp[2] = ref_px[0], ref_px[1], ref_px[2]
    for it in range(2):
        for k in range(9):
            a[k] = 0.0
        for i in mine:
            w = endpoint_weight(&s[i, 0], vp)
            for k in range(9):
                a[k] += w * lines[i, k // 3] * lines[i, k % 3]
        smallest_eigenvector(a, vp)
    if vp[2] < 0:
        vp[0], vp[1], vp[2] = -vp[0], -vp[1], -vp[2]
    out[0], out[1], out[2] = vp[0], vp[1], vp[2]


cdef bint smallest_2x2(double m00, double m01, double m11, double* x, double* y) noexcept nogil:
    """Unit eigenvector (x, y) of the symmetric [[m00, m01], [m01, m11]] with the smaller
    eigenvalue; False when both eigenvalues are equal (every direction fits alike)."""
    cdef double lam = 0.5 * (m00 + m11) - hypot(0.5 * (m00 - m11), m01)
    cdef double ax = m01, ay = lam - m00, bx = lam - m11, by = m01, nrm
    if hypot(bx, by) > hypot(ax, ay):
        ax, ay = bx, by
    nrm = hypot(ax, ay)
    if nrm < 1e-15:
        return False
    x[0], y[0] = ax / nrm, ay / nrm
    return True


cdef void set_horizontal(Frame* fr, const double* a, const double* b, double x, double y,
                         double* o) noexcept nogil:
    """``o`` ← the image of the horizontal direction ``x a + y b``, on ``o``'s side."""
    cdef double d[3]
    cdef int k
    for k in range(3):
        d[k] = x * a[k] + y * b[k]
    pixel_point(fr.f, fr.cx, fr.cy, d, d)
    if dot3(d, o) < 0:
        for k in range(3):
            d[k] = -d[k]
    for k in range(3):
        o[k] = d[k]


cdef bint box_ovps_fit(Frame* fr, double[:, ::1] s, double[:, ::1] lines, list legs,
                       double max_sin, double* o1, double* o2) noexcept:
    """O1, O2 refit in place as one box's yaw ψ about V3 (see
    :func:`companion.vision.obstacles.fit_box_ovps`); False, and both left as they were,
    when either OVP has no leg pointing at it within ``max_sin``."""
    cdef double a[3]
    cdef double b[3]
    cdef double n[3]
    cdef double up_a, na, nb, w, x, y
    # Σ w (n·a, n·b)ᵀ(n·a, n·b) over the legs of O1 (m1) and of O2 (m2).
    cdef double m1[3]
    cdef double m2[3]
    cdef double* m
    cdef bint seen1 = False, seen2 = False
    cdef Py_ssize_t i, k
    for k in range(3):
        m1[k] = m2[k] = 0.0
    direction_of(fr, o1, a)
    up_a = dot3(a, fr.d3)
    for k in range(3):
        a[k] -= up_a * fr.d3[k]
    if unit3(a) < 1e-9:
        return False
    cross3(fr.d3, a, b)
    for i in legs:
        if vp_sin(s[i, 0], s[i, 1], s[i, 2], s[i, 3], o1) <= max_sin:
            m, seen1 = m1, True
        elif vp_sin(s[i, 0], s[i, 1], s[i, 2], s[i, 3], o2) <= max_sin:
            m, seen2 = m2, True
        else:
            continue
        # The plane through the camera centre and the leg: normal Kᵀ l; a horizontal
        # direction d = x a + y b lies in it when x (n·a) + y (n·b) = 0.
        n[0] = fr.f * lines[i, 0]
        n[1] = fr.f * lines[i, 1]
        n[2] = fr.cx * lines[i, 0] + fr.cy * lines[i, 1] + lines[i, 2]
        unit3(n)
        na, nb = dot3(n, a), dot3(n, b)
        w = hypot(s[i, 2] - s[i, 0], s[i, 3] - s[i, 1])
        m[0] += w * na * na
        m[1] += w * na * nb
        m[2] += w * nb * nb
    if not (seen1 and seen2):
        return False
    # d1 = (x, y), d2 = (−y, x): O2's legs constrain (x, y) through (n·b, −n·a).
    if not smallest_2x2(m1[0] + m2[2], m1[1] - m2[1], m1[2] + m2[0], &x, &y):
        return False
    set_horizontal(fr, a, b, x, y, o1)
    set_horizontal(fr, a, b, -y, x, o2)
    return True


def fit_box_ovps(segments, ovps, layout_vps, double focal, double cx, double cy,
                 double max_angle_deg):
    """:func:`box_ovps_fit` over all ``segments`` (N×4) from ``ovps`` (2×3); 2×3 or None."""
    cdef double[:, ::1] s = np.ascontiguousarray(segments, dtype=float).reshape(-1, 4)
    cdef double[:, ::1] lines = np.empty((s.shape[0], 3))
    cdef double[:, ::1] vps = np.ascontiguousarray(layout_vps, dtype=float).reshape(3, 3)
    cdef double[:, ::1] out = np.array(ovps, dtype=float).reshape(2, 3)
    cdef Py_ssize_t i
    for i in range(s.shape[0]):
        segment_line(s[i, 0], s[i, 1], s[i, 2], s[i, 3], &lines[i, 0])
    cdef Frame fr
    fr.f, fr.cx, fr.cy = focal, cx, cy
    set_v3(&fr, &vps[2, 0])
    if not box_ovps_fit(&fr, s, lines, list(range(s.shape[0])),
                        sin(radians(max_angle_deg)), &out[0, 0], &out[1, 0]):
        return None
    return np.asarray(out)


cdef double edge_on_worst(Frame* fr, double[:, ::1] pc, double[:, ::1] ovps) noexcept:
    """The largest, over corners ``pc`` (K×2), of the smaller :func:`bearing_gap_deg` to
    the two OVPs (``ovps``' first two rows, homogeneous pixels); 90 without corners."""
    cdef double d1[3]
    cdef double d2[3]
    cdef double worst = 0.0, a, b
    cdef Py_ssize_t k
    if pc.shape[0] == 0:
        return 90.0
    direction_of(fr, &ovps[0, 0], d1)
    direction_of(fr, &ovps[1, 0], d2)
    for k in range(pc.shape[0]):
        a = bearing_gap_deg(fr, pc[k, 0], pc[k, 1], d1)
        b = bearing_gap_deg(fr, pc[k, 0], pc[k, 1], d2)
        a = a if a < b else b
        worst = a if a > worst else worst
    return worst


def edge_on_angle(corners_px, ovps, layout_vps, double focal, double cx, double cy):
    """:func:`edge_on_worst` of one obstacle (see
    :func:`companion.vision.obstacles.edge_on_angle_deg`). Degrees; 90 without corners."""
    cdef double[:, ::1] vps = np.ascontiguousarray(layout_vps, dtype=float).reshape(3, 3)
    cdef Frame fr
    fr.f, fr.cx, fr.cy = focal, cx, cy
    set_v3(&fr, &vps[2, 0])
    return edge_on_worst(&fr, np.ascontiguousarray(corners_px, dtype=float).reshape(-1, 2),
                         np.ascontiguousarray(ovps, dtype=float).reshape(-1, 3))


cdef list kept_obstacles(Frame* fr, Params* p, double[:, ::1] s, double[:, ::1] lines,
                         Hypotheses* found, double[:, ::1] pc, long long[::1] cs,
                         long long[::1] cn):
    """The obstacles of the hypotheses in ``found``, grouped by their OVPs
    (:func:`group_by_ovps`, :func:`obstacle`), less those edge-on at every corner: a line
    on the floor aimed at the camera's foot (:func:`edge_on_worst`)."""
    obstacles = []
    if found.count == 0:
        return obstacles
    for members in group_by_ovps(found, p.merge_deg):
        o = obstacle(fr, p, s, lines, members, found, pc, cs, cn)
        if edge_on_worst(fr, o[1], o[0]) >= p.edge_on_deg:
            obstacles.append(o)
    return obstacles


cdef tuple obstacle(Frame* fr, Params* p, double[:, ::1] s, double[:, ::1] lines,
                    list members, Hypotheses* found, double[:, ::1] pc, long long[::1] cs,
                    long long[::1] cn):
    """One obstacle from a group of hypotheses: OVPs refit on all legs, member corners
    joined. Returns (ovps 3×3, corners_px K×2, pairs, height_px, λ3, rule): ``rule`` the
    name (:data:`RULES`) of the rule that made the group's first hypothesis."""
    cdef Hypothesis* first = &found.items[<Py_ssize_t>members[0]]
    cdef Hypothesis* h
    cdef double ref1[3]
    cdef double ref2[3]
    cdef double o1[3]
    cdef double o2[3]
    cdef double e1[3]
    cdef double e2[3]
    cdef double fit_h, fit_o, ref_h, ref_o, a_s, b_s, a_n, b_n, height = 0.0, lam3 = INF
    cdef Py_ssize_t k, m, i
    pixel_point(fr.f, fr.cx, fr.cy, first.d1, ref1)
    pixel_point(fr.f, fr.cx, fr.cy, first.d2, ref2)
    paired = set()
    legs = set()
    extra_points = []
    for m in members:
        h = &found.items[m]
        if h.corner >= 0:
            paired.add(h.corner)
            legs.add(cs[h.corner])
            legs.add(cn[h.corner])
        for k in range(h.nlegs):
            legs.add(h.legs[k])
        for k in range(h.npoints):
            extra_points.append((h.points[2 * k], h.points[2 * k + 1]))
        height = h.edge if h.edge > height else height
        lam3 = h.lam3 if h.lam3 < lam3 else lam3
    paired = sorted(paired)
    legs = sorted(legs)
    # Refit each OVP on the horizontal legs of the paired corners that point at it.
    cdef double refit_deg = max(p.member_angle_deg * 3, 6.0)
    refit_ovp(s, lines, legs, ref1, refit_deg, o1)
    refit_ovp(s, lines, legs, ref2, refit_deg, o2)
    # Legs that are nearly parallel in the image fix their OVP poorly: a refit that breaks
    # the box model (λ3, eq. 8) is noise, not a better estimate, so keep the pair's OVPs.
    direction_of(fr, o1, e1)
    direction_of(fr, o2, e2)
    ovp_error(fr, e1, e2, &fit_h, &fit_o)
    ovp_error(fr, first.d1, first.d2, &ref_h, &ref_o)
    if fit_h > ref_h + p.refit_slack_deg or fit_o > ref_o + p.refit_slack_deg:
        for k in range(3):
            o1[k] = ref1[k]
            o2[k] = ref2[k]
    if p.box_fit:
        box_ovps_fit(fr, s, lines, legs, sin(radians(refit_deg)), o1, o2)
    # Further Table-I corners whose legs point at O1 and O2 join the obstacle (λ3).
    joined = list(paired)
    if paired:
        paired_set = set(paired)
        for k in range(cs.shape[0]):
            if k in paired_set:
                continue
            i = cs[k]
            a_s = vp_angle_deg(vp_sin(s[i, 0], s[i, 1], s[i, 2], s[i, 3], o1))
            b_s = vp_angle_deg(vp_sin(s[i, 0], s[i, 1], s[i, 2], s[i, 3], o2))
            i = cn[k]
            b_n = vp_angle_deg(vp_sin(s[i, 0], s[i, 1], s[i, 2], s[i, 3], o1))
            a_n = vp_angle_deg(vp_sin(s[i, 0], s[i, 1], s[i, 2], s[i, 3], o2))
            if min(max(a_s, a_n), max(b_s, b_n)) <= p.member_angle_deg:
                joined.append(k)
    points = []
    for x, y in [(pc[k, 0], pc[k, 1]) for k in joined] + extra_points:
        if all(hypot(x - kx, y - ky) > 3.0 for kx, ky in points):
            points.append((x, y))
    ovps = np.array([[o1[0], o1[1], o1[2]], [o2[0], o2[1], o2[2]],
                     [fr.v3[0], fr.v3[1], fr.v3[2]]])
    return (ovps, np.array(points, dtype=float).reshape(-1, 2), len(members), height, lam3,
            RULES[first.rule])


cdef bint room_edge_under(double[:, ::1] s, double[::1] lengths, Py_ssize_t[::1] room_idx,
                          list feet, double radius) noexcept:
    """Whether one room edge (``room_idx``: V1, V2) passes within ``radius`` of two of the
    ``feet`` (x, y), the lower ends of the edges hanging from a face's top edge: then the
    face's bottom edge points at a layout VP and the face is Manhattan (an aligned box
    whose top edge was found a few degrees off; a nearly frontal edge fixes its own
    direction poorly)."""
    cdef Py_ssize_t j, k
    cdef double ux, uy, t, dx, dy
    cdef int near
    for j in range(room_idx.shape[0]):
        k = room_idx[j]
        if lengths[k] <= 0:
            continue
        ux, uy = (s[k, 2] - s[k, 0]) / lengths[k], (s[k, 3] - s[k, 1]) / lengths[k]
        near = 0
        for x, y in feet:
            t = (x - s[k, 0]) * ux + (y - s[k, 1]) * uy
            t = 0.0 if t < 0 else (lengths[k] if t > lengths[k] else t)
            dx, dy = x - s[k, 0] - t * ux, y - s[k, 1] - t * uy
            near += dx * dx + dy * dy <= radius * radius
        if near >= 2:
            return True
    return False


cdef void receding_top_legs(Frame* fr, Params* p, double[:, ::1] s, tuple top,
                            const double* o, Py_ssize_t[::1] free_idx,
                            Hypothesis* h) noexcept:
    """Add to ``h.legs`` (up to its four) the free segments that leave an end of the top
    edge ``top`` (an :func:`edge_chains` chain; within ``radius_px``) at ``MIN_SIDE`` or
    more from it (``o``: its OVP), toward the horizon and ending below it: the top's
    receding edges, seen from above."""
    cdef Py_ssize_t j, b, e, k
    cdef double ex, ey
    for j in range(free_idx.shape[0]):
        b = free_idx[j]
        if h.nlegs >= 4 or vp_sin(s[b, 0], s[b, 1], s[b, 2], s[b, 3], o) <= MIN_SIDE:
            continue
        for e in range(2):
            ex, ey = top[2 * e], top[2 * e + 1]
            if end_distance(s, b, ex, ey) > p.radius_px:
                continue
            k = 2 if hypot(s[b, 0] - ex, s[b, 1] - ey) < hypot(s[b, 2] - ex, s[b, 3] - ey) else 0
            if 0 < below_horizon(fr, s[b, k], s[b, k + 1]) < below_horizon(fr, ex, ey):
                h.legs[h.nlegs] = b
                h.nlegs += 1
                break


cdef void hanging_faces(Frame* fr, Params* p, double[:, ::1] s, double[:, ::1] lines,
                        double[::1] lengths, Py_ssize_t[::1] free_idx, list chains,
                        Py_ssize_t[::1] room_idx, Hypotheses* found) except *:
    """One face's top edge with vertical edges hanging from it: a table's top seen from
    the front with its legs under the top's front edge, a box whose receding edges are
    too foreshortened to show, or a box taller than the camera seen from below its top;
    or a face's foot with its outline edges standing on it, where its top does not show
    (:func:`face_outline` makes each). The face's edge is horizontal, so its OVP is where
    it crosses the horizon; the other face's OVP is at a right angle to it through the
    focal length, as in :func:`single_halves`, whose test of V1 ⟂ V2 applies.

    The face's edge is a chain of collinear free legs (:func:`edge_chains`: the detector
    breaks an edge where its background changes), whose longest member, which gives its
    line, is ``5 min_edge_px`` long or more (shorter ones fix their direction too poorly),
    its OVP away from V1 and V2.

    A top above the horizon is a face's seen from below, its only sign of the face's yaw
    (the receding faces edge-on, the top face out of sight), and a foot is seen from
    above with its receding edges hidden behind the face: ``noise_px`` at their ends may
    move their OVP by at most ``single_face_tol_deg`` (:func:`crossing_noise_sq`; near the
    horizon, as an aligned cabinet's top seen at eye level, the crossing is anywhere).

    Where a top's receding edges show at its ends (:func:`receding_top_legs`, only from
    above), both OVPs are fitted to them and the top edge as one box's yaw
    (:func:`box_ovps_fit`), which the receding edges fix well where the top edge's far
    crossing does not."""
    cdef double o[3]
    cdef double d1[3]
    cdef double d2[3]
    cdef double mid
    cdef bint noisy, alone
    cdef Py_ssize_t a
    if not chains or not room_vouches_for_focal(fr, p):
        return
    for top in edge_chains(s, lengths, lines, free_idx, p):
        a = top[5]
        if lengths[a] < 5 * p.min_edge_px:
            continue
        if not intersect(&lines[a, 0], fr.horizon, o):
            continue
        direction_of(fr, o, d1)
        if not off_layout(fr, p, d1):
            continue
        cross3(fr.d3, d1, d2)
        if unit3(d2) <= 0:
            continue
        mid = below_horizon(fr, (s[a, 0] + s[a, 2]) / 2, (s[a, 1] + s[a, 3]) / 2)
        noisy = sqrt(crossing_noise_sq(fr, p, s, a, d2)) > p.single_face_tol_deg
        for at_foot in range(2):
            # A foot lies below the horizon. A top above it, or a foot, is the face's only
            # sign of its yaw: its OVP must stand pixel noise.
            alone = at_foot or mid <= 0
            if at_foot and mid <= 0 or alone and noisy:
                continue
            face_outline(fr, p, s, lines, lengths, chains, room_idx, top, o, d1, d2,
                         at_foot, alone, free_idx, found)


cdef void face_outline(Frame* fr, Params* p, double[:, ::1] s, double[:, ::1] lines,
                       double[::1] lengths, list chains, Py_ssize_t[::1] room_idx, tuple edge,
                       const double* o, const double* d1, const double* d2, bint at_foot,
                       bint alone, Py_ssize_t[::1] free_idx, Hypotheses* found) except *:
    """One hypothesis for :func:`hanging_faces`, appended to ``found``: a face from its
    horizontal ``edge`` (an :func:`edge_chains` chain whose OVP is the direction ``d1``,
    the pixel point ``o``, ``d2`` at a right angle to it) and the vertical edges ``chains``
    whose upper ends (``at_foot``: lower ends) lie on its line, between its ends: two or
    more, one on each side of its middle (the edges of one face, not one edge twice), each
    upright (at ``MIN_SIDE`` or more from the face's edge, pointing at V3, ``fr.v3``, within
    ``member_angle_deg``), the outermost two spanning at least ``MIN_TOP_SPAN`` of a top's
    length.

    An edge may stop short of the face's edge by ``radius_px``, and, where that edge is
    the face's only sign of its yaw (``alone``: a top seen from below, or a foot; the
    edges fade against a ceiling, or a contact shadow, shaded like the face), where it
    lies wholly on one side by ``leg_gap_frac`` of its length more, as a corner's vertical
    leg may. A foot may stop short of the outermost edges as far as
    :func:`edge_chains` joins pieces across, but not run on past them (something in front
    of them); where each outer edge's line meets it is a floor contact. No room edge may
    join two of the edges' other ends (:func:`room_edge_under`)."""
    cdef double c[3]
    cdef double o1[3]
    cdef double o2[3]
    cdef double e1[3]
    cdef double e2[3]
    cdef double ux, uy, t, t0, t1, middle, reach, off, lo, hi, tallest, side, gap
    cdef Py_ssize_t a = edge[5], k, near, b
    cdef Hypothesis* h
    ux, uy = (s[a, 2] - s[a, 0]) / lengths[a], (s[a, 3] - s[a, 1]) / lengths[a]
    t0 = (edge[0] - s[a, 0]) * ux + (edge[1] - s[a, 1]) * uy
    t1 = (edge[2] - s[a, 0]) * ux + (edge[3] - s[a, 1]) * uy
    t0, t1 = min(t0, t1), max(t0, t1)
    middle = (t0 + t1) / 2
    # A foot's ends reach as far as edge_chains joins a piece: the detector stops a foot
    # short of the face's corner, in the shadow where face and floor meet.
    reach = p.radius_px + (p.leg_gap_frac * (t1 - t0) if at_foot else 0.0)
    cdef double max_lean = sin(radians(p.member_angle_deg))
    lo, hi, tallest = INF, -INF, 0.0
    ends = []
    cdef int upright = 0
    for chain in chains:
        # near: the chain's end on the face's edge (its upper end, or at a foot its lower)
        near = 0 if below_horizon(fr, chain[0], chain[1]) < below_horizon(
            fr, chain[2], chain[3]) else 2
        if at_foot:
            near = 2 - near
        off = lines[a, 0] * chain[near] + lines[a, 1] * chain[near + 1] + lines[a, 2]
        gap = p.radius_px
        if alone:  # a near end on the chain's own side stops short
            side = lines[a, 0] * chain[2 - near] + lines[a, 1] * chain[3 - near] + lines[a, 2]
            gap += p.leg_gap_frac * chain[4] if off * side > 0 else 0.0
        t = (chain[near] - s[a, 0]) * ux + (chain[near + 1] - s[a, 1]) * uy
        if fabs(off) > gap or t < t0 - reach or t > t1 + reach:
            continue
        ends.append((chain[2 - near], chain[3 - near]))
        # Counted only if upright: not along the face's edge, and not a line on the floor
        # aimed near V3 (a rug's stripe); the room-edge test below takes every one.
        if (fabs((chain[2] - chain[0]) * uy - (chain[3] - chain[1]) * ux) < MIN_SIDE * chain[4]
                or vp_sin(chain[0], chain[1], chain[2], chain[3], fr.v3) > max_lean):
            continue
        if at_foot:  # where the edge's line meets the foot: the floor contact
            b = chain[5]
            if not intersect(&lines[b, 0], &lines[a, 0], c) or fabs(c[2]) < 1e-12:
                continue
            point = (chain[2 - near], chain[3 - near], c[0] / c[2], c[1] / c[2])
        else:
            point = (chain[near], chain[near + 1])
        upright += 1
        if t < lo:
            lo, at_lo = t, point
        if t > hi:
            hi, at_hi = t, point
        tallest = max(tallest, chain[4])
    if upright < 2 or lo > middle or hi < middle:
        return
    # A face's outline edges stand at its top's ends, a table's legs a little inside them;
    # a top running on past both by more than they span is no top of theirs (a line
    # across the sides of two things that stand close together).
    if not at_foot and hi - lo < MIN_TOP_SPAN * (t1 - t0):
        return
    if at_foot and (t0 < lo - reach or t1 > hi + reach):
        return
    if room_edge_under(s, lengths, room_idx, ends, p.radius_px):
        return
    h = new_hypothesis(found, STANDING_FACE if at_foot else HANGING_FACE)
    set_ovps(h, d1, d2, horizon_error(fr, d1), tallest)
    h.legs[0] = a
    h.nlegs = 1
    if not at_foot:  # a top's receding edges show only from above; a foot's are hidden
        receding_top_legs(fr, p, s, edge, o, free_idx, h)
        if h.nlegs > 1:
            # The top edge's far crossing fixes the other OVP poorly when the face is seen
            # nearly front-on (about 4° of bearing per pixel in the closed loop's room):
            # both OVPs are fitted as one box's yaw to the top edge and the receding ones.
            pixel_point(fr.f, fr.cx, fr.cy, d1, o1)
            if intersect(&lines[h.legs[1], 0], fr.horizon, o2) and box_ovps_fit(
                    fr, s, lines, [h.legs[k] for k in range(h.nlegs)], sin(radians(3.0)),
                    o1, o2):
                direction_of(fr, o1, e1)
                direction_of(fr, o2, e2)
                set_ovps(h, e1, e2, horizon_error(fr, e1), tallest)
    points = at_lo + at_hi  # (x, y) pairs: two tops, or two edges' upper ends and feet
    h.npoints = len(points) // 2
    for k in range(len(points)):
        h.points[k] = points[k]


def find(segments, corner_points, corner_s, corner_n, corner_r, layout_vps, double focal,
         double cx, double cy, free_legs, labels, Py_ssize_t vertical_label, params,
         double radius_px, double leg_gap_frac, double min_leg_sin, bint room_seen,
         double noise_px, bint focal_settled=False):
    """Obstacles from Table-I corners and vertical edges (see
    :func:`companion.vision.obstacles.find_obstacles`), unsorted: a list of (ovps 3×3,
    corners_px K×2, pairs, height_px, λ3, rule). The fewer-corner rules run, all of them,
    only when the corner pairs found nothing; an obstacle edge-on at every corner
    (:func:`edge_on_worst` below ``edge_on_deg``) counts as nothing."""
    cdef Params p
    p.collinear_px = params.collinear_px
    p.min_edge_px = params.min_edge_px
    p.horizon_tol_deg = params.horizon_tol_deg
    p.orthogonal_tol_deg = params.orthogonal_tol_deg
    p.single_corner_orthogonal_tol_deg = params.single_corner_orthogonal_tol_deg
    p.single_corner_noise_deg = params.single_corner_noise_deg
    p.single_face_tol_deg = params.single_face_tol_deg
    p.room_right_angle_tol_deg = (params.settled_focal_tol_deg if focal_settled
                                  else params.single_face_tol_deg)
    p.non_manhattan_min_deg = params.non_manhattan_min_deg
    p.merge_deg = params.merge_deg
    p.member_angle_deg = params.member_angle_deg
    p.refit_slack_deg = params.refit_slack_deg
    p.box_fit = params.box_fit
    p.hidden_edge_corners = params.hidden_edge_corners
    p.radius_px = radius_px
    p.leg_gap_frac = leg_gap_frac
    p.noise_px = noise_px
    p.edge_on_deg = params.edge_on_deg
    cdef double[:, ::1] s = np.ascontiguousarray(segments, dtype=float).reshape(-1, 4)
    cdef Py_ssize_t n = s.shape[0], i, k, g, nh
    if n == 0:
        return []
    cdef double[:, ::1] vps = np.ascontiguousarray(layout_vps, dtype=float).reshape(3, 3)
    cdef double[:, ::1] lines = np.empty((n, 3))
    cdef double[::1] lengths = np.empty(n)
    for i in range(n):
        segment_line(s[i, 0], s[i, 1], s[i, 2], s[i, 3], &lines[i, 0])
        lengths[i] = hypot(s[i, 2] - s[i, 0], s[i, 3] - s[i, 1])
    cdef Frame fr
    fr.f, fr.cx, fr.cy = focal, cx, cy
    set_v3(&fr, &vps[2, 0])
    direction_of(&fr, &vps[0, 0], fr.l1)
    direction_of(&fr, &vps[1, 0], fr.l2)
    # The horizon: the image line of all directions ⟂ V3, scaled to pixel distances.
    fr.horizon[0] = fr.d3[0] / focal
    fr.horizon[1] = fr.d3[1] / focal
    fr.horizon[2] = fr.d3[2] - (cx * fr.d3[0] + cy * fr.d3[1]) / focal
    cdef double hn = hypot(fr.horizon[0], fr.horizon[1])
    if hn > 0:
        fr.horizon[0] /= hn
        fr.horizon[1] /= hn
        fr.horizon[2] /= hn
    else:
        fr.horizon[0], fr.horizon[1], fr.horizon[2] = 0.0, 0.0, 1.0
    lab = np.asarray(labels)
    cdef Py_ssize_t[::1] verticals = np.flatnonzero(lab == vertical_label)
    cdef Py_ssize_t[::1] free_idx = np.flatnonzero(free_legs)
    cdef double[:, ::1] pc = np.ascontiguousarray(corner_points, dtype=float).reshape(-1, 2)
    cdef long long[::1] cs = np.ascontiguousarray(corner_s, dtype=np.int64)
    cdef long long[::1] cn = np.ascontiguousarray(corner_n, dtype=np.int64)
    cdef long long[::1] cr = np.ascontiguousarray(corner_r, dtype=np.int64)
    cdef Py_ssize_t nc = pc.shape[0]

    cdef Hypotheses found
    found.items = NULL
    found.count = found.cap = 0
    cdef Hypotheses halves
    halves.items = NULL
    halves.count = halves.cap = 0
    cdef double[:, ::1] far = np.empty((max(nc, 1), 2))
    cdef double[::1] reach = np.empty(max(nc, 1))
    cdef unsigned char[::1] usable = np.zeros(max(nc, 1), np.uint8)
    cdef Py_ssize_t* partners = <Py_ssize_t*>malloc(max(free_idx.shape[0], 1) * sizeof(Py_ssize_t))
    cdef double d1[3]
    cdef double d2[3]
    cdef double o1[3]
    cdef double o2[3]
    cdef double lam3
    cdef int rule
    cdef Hypothesis* h
    cdef Py_ssize_t[::1] room_idx = np.flatnonzero((lab >= 0) & (lab != vertical_label))
    # V1 or V2 beyond doubt (:func:`companion.vision.corners.obstacle_legs`).
    cdef Py_ssize_t[::1] manhattan_idx = np.flatnonzero(
        ~np.asarray(free_legs, bool) & (lab != vertical_label))
    try:
        if nc and verticals.shape[0]:
            # Pairs (eqs. 5–8): each Table-I corner's vertical edge followed to its other
            # end (eqs. 6, 7), where the non-Manhattan legs form C_h.
            far_ends(s, lines, pc, cr, verticals, &p, far, reach, usable)
            for g in range(nc):
                if not usable[g] or not foot_legs_apart(&fr, s, pc[g, 0], pc[g, 1],
                                                        far[g, 0], far[g, 1], cs[g], cn[g]):
                    continue
                nh = partner_legs(s, lines, pc[g, 0], pc[g, 1], far[g, 0], far[g, 1],
                                  reach[g], cs[g], cn[g], free_idx, &p, partners)
                # With no leg of C_h in sight, both OVPs where C_g's legs cross the horizon,
                # unless a room edge leaves the vertical edge's far end: then the edge is a
                # door frame's or an aligned box's, and the legs a rug's or a shadow's
                # corner at its foot (room_edge_at). At C_g, and where the edge runs out of
                # the frame, the room's edges that the box hides end too: no proof there.
                rule = CORNER_PAIR
                if not partner_ovps(&fr, &p, lines, cs[g], cn[g], partners, nh, d1, d2, &lam3):
                    rule = SINGLE_CORNER
                    if reach[g] < 2 * p.min_edge_px or not horizon_ovps(
                            &fr, &p, s, lines, cs[g], cn[g], d1, d2, &lam3):
                        continue
                    pixel_point(fr.f, fr.cx, fr.cy, d1, o1)
                    pixel_point(fr.f, fr.cx, fr.cy, d2, o2)
                    if not at_border(&fr, far[g, 0], far[g, 1], p.radius_px):
                        if room_edge_at(s, lengths, (pc[g, 0], pc[g, 1], far[g, 0], far[g, 1],
                                                     reach[g]), room_idx, o1, o2, &p, False):
                            continue
                    # An edge that stops short of C_g and stands on a room edge there is
                    # a door post's or an aligned box's; C_g below it, a rug's corner.
                    if stands_short(&fr, s, lengths, cr[g], pc[g, 0], pc[g, 1], far[g, 0],
                                    far[g, 1], room_idx, o1, o2, &p):
                        continue
                h = new_hypothesis(&found, rule)
                set_ovps(h, d1, d2, lam3, reach[g])
                h.corner = g
        # Vertical edges the detector did not see, implied by leg junctions above each other.
        junctions = leg_junctions(s, lines, lengths, free_idx, min_leg_sin, &p)
        junction_pairs(&fr, &p, s, lines, junctions, &found)
        # Vertical edges whose ends show only two-leg corners (outline edges, low contrast).
        chains = edge_chains(s, lengths, lines, verticals, &p)
        edges = edge_legs(&fr, s, lengths, chains, free_idx, room_idx, &p)
        silhouette_halves(&fr, &p, s, lengths, lines, edges, manhattan_idx, &halves)
        pair_halves(&fr, &p, s, lines, &halves, &found)
        # Step 0 is the above. When it finds nothing, every fewer-corner rule runs and
        # their hypotheses are grouped together: the obstacle that drives η is then chosen
        # among all of them (find_obstacles' order), not taken from the first rule that
        # found anything, which may be a weaker rule's wrong reading of another piece.
        obstacles = kept_obstacles(&fr, &p, s, lines, &found, pc, cs, cn)
        if obstacles:
            return obstacles
        found.count = 0
        edge_horizon_pairs(&fr, &p, s, lengths, lines, edges, manhattan_idx, &found)
        if p.hidden_edge_corners:
            junction_edge_pairs(&fr, &p, s, lines, lengths, edges, junctions, room_idx,
                                &found)
        if room_seen:
            single_halves(&fr, &p, &halves, &found)
            hanging_faces(&fr, &p, s, lines, lengths, free_idx, chains, room_idx, &found)
        return kept_obstacles(&fr, &p, s, lines, &found, pc, cs, cn)
    finally:
        free(found.items)
        free(halves.items)
        free(partners)
