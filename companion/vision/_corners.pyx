"""Compiled loops of the corner stage; the method (eqs. 2–4) is described in
:mod:`companion.vision.corners`, which calls these functions."""

import numpy as np

from libc.math cimport fabs, sqrt
from libc.stdlib cimport free, malloc, qsort, realloc

from companion.vision._geometry cimport end_distance, hypot, segment_line

cdef double INF = float("inf")


cdef struct Keyed:
    double key
    Py_ssize_t index


cdef int _by_key(const void* a, const void* b) noexcept nogil:
    """Order of (key, index): a stable sort by key."""
    cdef const Keyed* x = <const Keyed*>a
    cdef const Keyed* y = <const Keyed*>b
    if x.key < y.key:
        return -1
    if x.key > y.key:
        return 1
    return (x.index > y.index) - (x.index < y.index)


cdef void* realloc_or_die(void* p, size_t size) except NULL:
    cdef void* q = realloc(p, size)
    if q == NULL:
        free(p)
        raise MemoryError()
    return q


cdef Py_ssize_t close_end_pairs(double[:, ::1] s, const Py_ssize_t* rows, Py_ssize_t nrows,
                                double radius, Py_ssize_t** out):
    """Pairs of endpoints at most ``radius`` apart among segments ``s[rows]``, as flat
    endpoint indices ``2·k + end`` over ``rows`` (pairs of ``*out``, malloc'd). A sweep
    along x: after sorting the endpoints by x only those within ``radius`` in x are
    compared, so the cost grows with the number of close pairs, not with the square."""
    cdef Py_ssize_t m = 2 * nrows, i, j, k, count = 0, cap = 64
    xs_arr = np.empty(m)
    ys_arr = np.empty(m)
    cdef double[::1] xs = xs_arr, ys = ys_arr
    for k in range(m):
        xs[k] = s[rows[k // 2], 2 * (k % 2)]
        ys[k] = s[rows[k // 2], 2 * (k % 2) + 1]
    cdef Py_ssize_t[::1] order = np.argsort(xs_arr, kind="stable")
    cdef Py_ssize_t* pairs = <Py_ssize_t*>malloc(2 * cap * sizeof(Py_ssize_t))
    cdef double xa, ya, dx, dy, r2 = radius * radius
    for i in range(m):
        xa = xs[order[i]]
        ya = ys[order[i]]
        j = i + 1
        while j < m and xs[order[j]] <= xa + radius:
            dx = xa - xs[order[j]]
            dy = ya - ys[order[j]]
            if dx * dx + dy * dy <= r2:
                if count == cap:
                    cap *= 2
                    pairs = <Py_ssize_t*>realloc_or_die(pairs, 2 * cap * sizeof(Py_ssize_t))
                pairs[2 * count] = order[i]
                pairs[2 * count + 1] = order[j]
                count += 1
            j += 1
    out[0] = pairs
    return count


def loose_ends(segments, double radius_px, among=None):
    """Which segment ends meet no other segment's end within ``radius_px`` (N×2 bool);
    with ``among`` (N bool), only those segments count, and the others are not loose."""
    cdef double[:, ::1] s = np.ascontiguousarray(segments, dtype=float).reshape(-1, 4)
    cdef Py_ssize_t n = s.shape[0], k, count, m = 0
    out = np.zeros((n, 2), dtype=bool)
    cdef unsigned char[:, ::1] loose = out.view(np.uint8)
    cdef const unsigned char[::1] use
    if among is not None:
        use = np.ascontiguousarray(among, dtype=bool).reshape(-1).view(np.uint8)
    cdef Py_ssize_t* rows = <Py_ssize_t*>malloc(max(n, 1) * sizeof(Py_ssize_t))
    cdef Py_ssize_t* pairs = NULL
    cdef Py_ssize_t a, b
    for k in range(n):
        if among is None or use[k]:
            rows[m] = k
            m += 1
            loose[k, 0] = loose[k, 1] = 1
    count = close_end_pairs(s, rows, m, radius_px, &pairs)
    for k in range(count):
        a = pairs[2 * k]
        b = pairs[2 * k + 1]
        if a // 2 != b // 2:
            loose[rows[a // 2], a % 2] = 0
            loose[rows[b // 2], b % 2] = 0
    free(pairs)
    free(rows)
    return out


cdef inline double leg_term(double[:, ::1] s, double[::1] lengths, Py_ssize_t i,
                            double x, double y) noexcept nogil:
    """One leg's term of eqs. 3–4: ``|d(p_c, p_k) − l_k/2|``."""
    cdef double mx = 0.5 * (s[i, 0] + s[i, 2]), my = 0.5 * (s[i, 1] + s[i, 3])
    return fabs(sqrt((mx - x) * (mx - x) + (my - y) * (my - y)) - lengths[i] / 2.0)


def corner_projections(segments, labels, Py_ssize_t vertical_label, double radius_px,
                       double min_leg_sin, double min_vertical_leg_sin, double leg_gap_frac,
                       Py_ssize_t top_k):
    """Corner projections ``{L_s, L_n, L_r}`` (eq. 2) ranked by Λ_C (eq. 4).

    ``L_s``, ``L_n``: segments not labelled ``vertical_label`` with endpoints within
    ``radius_px`` of each other, at least ``asin(min_leg_sin)`` apart, meeting at ``p_c``
    within ``radius_px`` of an end of each. ``L_r``: the vertical segment whose line passes
    within ``radius_px / 2`` of ``p_c``, whose nearer end is within
    ``radius_px + leg_gap_frac · l_r`` of it, at least ``asin(min_vertical_leg_sin)`` from
    both other legs, with the smallest eq.-4 term. Returns ``(points K×2, s, n, r,
    Λ_LP, Λ_C)``, best first, at most ``top_k``.
    """
    cdef double[:, ::1] s = np.ascontiguousarray(segments, dtype=float).reshape(-1, 4)
    cdef long long[::1] lab = np.ascontiguousarray(labels, dtype=np.int64)
    cdef Py_ssize_t n = s.shape[0], i, j, k, v, nv = 0, no = 0, count, ncorner = 0
    cdef Py_ssize_t* verticals = <Py_ssize_t*>malloc(max(n, 1) * sizeof(Py_ssize_t))
    cdef Py_ssize_t* others = <Py_ssize_t*>malloc(max(n, 1) * sizeof(Py_ssize_t))
    for i in range(n):
        if lab[i] == vertical_label:
            verticals[nv] = i
            nv += 1
        else:
            others[no] = i
            no += 1
    if nv == 0 or no < 2:
        free(verticals)
        free(others)
        return _empty()
    cdef double[:, ::1] lines = np.empty((n, 3))
    cdef double[:, ::1] dirs = np.zeros((n, 2))
    cdef double[::1] lengths = np.empty(n)
    for i in range(n):
        segment_line(s[i, 0], s[i, 1], s[i, 2], s[i, 3], &lines[i, 0])
        lengths[i] = hypot(s[i, 2] - s[i, 0], s[i, 3] - s[i, 1])
        if lengths[i] > 0:
            dirs[i, 0] = (s[i, 2] - s[i, 0]) / lengths[i]
            dirs[i, 1] = (s[i, 3] - s[i, 1]) / lengths[i]

    # 1. L_s, L_n: non-vertical segments whose endpoints meet, in order of (s, n).
    cdef Py_ssize_t* pairs = NULL
    count = close_end_pairs(s, others, no, radius_px, &pairs)
    cdef Keyed* keys = <Keyed*>malloc(max(count, 1) * sizeof(Keyed))
    cdef Py_ssize_t nkeys = 0, a, b, lo, hi
    for k in range(count):
        a = pairs[2 * k] // 2
        b = pairs[2 * k + 1] // 2
        if a == b:
            continue
        lo, hi = (a, b) if a < b else (b, a)
        keys[nkeys].key = <double>(lo * no + hi)
        keys[nkeys].index = lo * no + hi
        nkeys += 1
    free(pairs)
    qsort(keys, nkeys, sizeof(Keyed), _by_key)

    cand_arr = np.empty((max(nkeys, 1), 2))
    cdef double[:, ::1] pc = cand_arr
    cdef Py_ssize_t[::1] cs = np.empty(max(nkeys, 1), np.intp)
    cdef Py_ssize_t[::1] cn = np.empty(max(nkeys, 1), np.intp)
    cdef double p[3]
    cdef double nrm, x, y
    cdef Py_ssize_t si, ni
    for k in range(nkeys):
        if k > 0 and keys[k].index == keys[k - 1].index:
            continue
        si = others[keys[k].index // no]
        ni = others[keys[k].index % no]
        if fabs(dirs[si, 0] * dirs[ni, 1] - dirs[si, 1] * dirs[ni, 0]) < min_leg_sin:
            continue
        p[0] = lines[si, 1] * lines[ni, 2] - lines[si, 2] * lines[ni, 1]
        p[1] = lines[si, 2] * lines[ni, 0] - lines[si, 0] * lines[ni, 2]
        p[2] = lines[si, 0] * lines[ni, 1] - lines[si, 1] * lines[ni, 0]
        nrm = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
        if nrm <= 0 or fabs(p[2] / nrm) <= 1e-12:
            continue
        x = (p[0] / nrm) / (p[2] / nrm)
        y = (p[1] / nrm) / (p[2] / nrm)
        # p_c must sit at an end of both legs, not along their extensions or interiors.
        if end_distance(s, si, x, y) > radius_px or end_distance(s, ni, x, y) > radius_px:
            continue
        pc[ncorner, 0] = x
        pc[ncorner, 1] = y
        cs[ncorner] = si
        cn[ncorner] = ni
        ncorner += 1
    free(keys)
    free(others)

    # 2. L_r: the vertical segment through p_c with the smallest eq.-4 term.
    cdef Py_ssize_t[::1] cr = np.empty(max(ncorner, 1), np.intp)
    cdef double[::1] lam_r = np.empty(max(ncorner, 1))
    cdef Py_ssize_t kept = 0, best
    cdef double cost, best_cost
    for k in range(ncorner):
        x = pc[k, 0]
        y = pc[k, 1]
        si = cs[k]
        ni = cn[k]
        best = -1
        best_cost = INF
        for j in range(nv):
            v = verticals[j]
            if fabs(x * lines[v, 0] + y * lines[v, 1] + lines[v, 2]) > radius_px / 2.0:
                continue
            if end_distance(s, v, x, y) > radius_px + leg_gap_frac * lengths[v]:
                continue
            if fabs(dirs[si, 0] * dirs[v, 1] - dirs[si, 1] * dirs[v, 0]) < min_vertical_leg_sin:
                continue
            if fabs(dirs[ni, 0] * dirs[v, 1] - dirs[ni, 1] * dirs[v, 0]) < min_vertical_leg_sin:
                continue
            cost = leg_term(s, lengths, v, x, y)
            if cost < best_cost:
                best_cost = cost
                best = v
        if best < 0:
            continue
        pc[kept, 0] = x
        pc[kept, 1] = y
        cs[kept] = si
        cn[kept] = ni
        cr[kept] = best
        lam_r[kept] = best_cost
        kept += 1
    free(verticals)
    if kept == 0:
        return _empty()

    # Λ_LP (eq. 3), Λ_C (eq. 4); the best top_k by Λ_C, ties in order of discovery.
    cdef Keyed* order = <Keyed*>malloc(kept * sizeof(Keyed))
    cdef double[::1] lam_lp = np.empty(kept)
    for k in range(kept):
        lam_lp[k] = leg_term(s, lengths, cs[k], pc[k, 0], pc[k, 1]) \
            + leg_term(s, lengths, cn[k], pc[k, 0], pc[k, 1])
        order[k].key = lam_lp[k] + lam_r[k]
        order[k].index = k
    qsort(order, kept, sizeof(Keyed), _by_key)
    cdef Py_ssize_t m = min(kept, top_k)
    points = np.empty((m, 2))
    s_out = np.empty(m, np.int64)
    n_out = np.empty(m, np.int64)
    r_out = np.empty(m, np.int64)
    lp_out = np.empty(m)
    c_out = np.empty(m)
    cdef double[:, ::1] po = points
    cdef long long[::1] so = s_out, no_ = n_out, ro = r_out
    cdef double[::1] lpo = lp_out, lco = c_out
    for i in range(m):
        k = order[i].index
        po[i, 0] = pc[k, 0]
        po[i, 1] = pc[k, 1]
        so[i] = cs[k]
        no_[i] = cn[k]
        ro[i] = cr[k]
        lpo[i] = lam_lp[k]
        lco[i] = order[i].key
    free(order)
    return points, s_out, n_out, r_out, lp_out, c_out


def _empty():
    z = np.empty(0, np.int64)
    return np.empty((0, 2)), z, z.copy(), z.copy(), np.empty(0), np.empty(0)
