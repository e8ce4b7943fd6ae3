"""The exact (comparison-based) triangle–triangle distance, one pair at a time.

``exact_pair`` is the oracle for every other kernel. It returns the squared
distance and a closest pair of points as the minimum over

* 9 edge–edge closest points (Ericson, *Real-Time Collision Detection* §5.1.9,
  without branches so that the loop over pairs vectorises);
* 6 vertex–face candidates, taken only where the vertex projects into the
  interior of the other triangle (a projection outside is dominated by an
  edge–edge candidate, so the point–edge half of a point–triangle test is
  redundant);
* 6 edge–face crossings (distance 0 at the crossing point): two non-coplanar
  intersecting triangles always have an edge of one crossing the other, and
  coplanar overlaps are caught by the edge–edge and vertex–face candidates.

Barycentric coordinates use the triangle's dual basis (``g1, g2`` with
``g_i · e_j = δ_ij``), i.e. the inverse of its 2×2 Gram matrix, built once per
triangle by :func:`triangle_frame` (the host builds frames in float64 and puts
each triangle's largest angle at vertex 0, where they are best conditioned).
Slivers whose ``sin²`` of that angle is below ``tiny`` (the host passes ``64·ulp``
of the kernel's precision) get no face candidates; their edges carry the
distance, within the sliver's width. All inputs are in a pair-local frame.

Helpers here are written as flat scalar code: they are inlined at Numba-IR
level (see :mod:`engine.kernels.jit`), whose cost grows quickly with
nested call sites.
"""

from __future__ import annotations

from numba import njit

from engine.kernels.jit import INLINE, select, sqrt


@njit(**INLINE)
def triangle_frame(v0, v1, v2, one, tiny):
    """Translation-invariant frame of one triangle.

    Returns ``(normal, g1, g2, inv_len2, valid)``: unit ``normal``; dual vectors
    with ``(p - v0)·g1`` and ``(p - v0)·g2`` the barycentric coordinates (along
    ``v1 - v0`` and ``v2 - v0``) of the projection of ``p``; ``inv_len2`` the
    inverse squared lengths of the edges ``v0→v1, v1→v2, v0→v2``; ``valid`` False
    for slivers (no reliable plane).
    """
    zero = one - one
    e1x, e1y, e1z = v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]
    e2x, e2y, e2z = v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2]
    e3x, e3y, e3z = v2[0] - v1[0], v2[1] - v1[1], v2[2] - v1[2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    d00 = e1x * e1x + e1y * e1y + e1z * e1z
    d01 = e1x * e2x + e1y * e2y + e1z * e2z
    d11 = e2x * e2x + e2y * e2y + e2z * e2z
    den = nx * nx + ny * ny + nz * nz
    valid = den > tiny * (d00 * d11)
    den = select(valid, den, one)
    inv = one / den
    g1 = (
        (d11 * e1x - d01 * e2x) * inv,
        (d11 * e1y - d01 * e2y) * inv,
        (d11 * e1z - d01 * e2z) * inv,
    )
    g2 = (
        (d00 * e2x - d01 * e1x) * inv,
        (d00 * e2y - d01 * e1y) * inv,
        (d00 * e2z - d01 * e1z) * inv,
    )
    s = one / sqrt(den)
    d22 = e3x * e3x + e3y * e3y + e3z * e3z
    # 0 for a zero-length edge: its closest point is then its start.
    inv_len2 = (
        select(d00 > zero, one / select(d00 > zero, d00, one), zero),
        select(d22 > zero, one / select(d22 > zero, d22, one), zero),
        select(d11 > zero, one / select(d11 > zero, d11, one), zero),
    )
    return (nx * s, ny * s, nz * s), g1, g2, inv_len2, valid


@njit(**INLINE)
def segment_segment(p0, d1, q0, d2, one):
    """Closest points of segments ``p0 + s·d1`` and ``q0 + t·d2``, s, t in [0, 1].

    Returns ``(squared distance, point on first, point on second)``.
    Branch-free form of Ericson §5.1.9, including its zero-length cases. The
    denominator ``a·e − b²`` and its numerator are evaluated as ``|d1 × d2|²`` and
    ``(d1 × d2)·(d2 × r)`` (Lagrange's identity): the difference of products is
    pure rounding noise for nearly parallel segments.
    """
    zero = one - one
    rx, ry, rz = p0[0] - q0[0], p0[1] - q0[1], p0[2] - q0[2]
    a = d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]
    e = d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2]
    b = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]
    c = d1[0] * rx + d1[1] * ry + d1[2] * rz
    f = d2[0] * rx + d2[1] * ry + d2[2] * rz
    nx = d1[1] * d2[2] - d1[2] * d2[1]
    ny = d1[2] * d2[0] - d1[0] * d2[2]
    nz = d1[0] * d2[1] - d1[1] * d2[0]
    mx = d2[1] * rz - d2[2] * ry
    my = d2[2] * rx - d2[0] * rz
    mz = d2[0] * ry - d2[1] * rx
    den = nx * nx + ny * ny + nz * nz
    num = nx * mx + ny * my + nz * mz
    ia = one / select(a > zero, a, one)
    ie = one / select(e > zero, e, one)
    s_lo = min(max(-c * ia, zero), one)
    s_hi = min(max((b - c) * ia, zero), one)
    s = select(den > zero, min(max(num / select(den > zero, den, one), zero), one), zero)
    t = (b * s + f) * ie
    s = select(t < zero, s_lo, s)
    s = select(t > one, s_hi, s)
    t = min(max(t, zero), one)
    s = select(e > zero, s, s_lo)
    p = (p0[0] + s * d1[0], p0[1] + s * d1[1], p0[2] + s * d1[2])
    q = (q0[0] + t * d2[0], q0[1] + t * d2[1], q0[2] + t * d2[2])
    wx, wy, wz = p[0] - q[0], p[1] - q[1], p[2] - q[2]
    return wx * wx + wy * wy + wz * wz, p, q


@njit(**INLINE)
def _height(v, o, frame):
    """Height over the face and barycentrics (u, w) of the projection of ``v``."""
    n, g1, g2 = frame[0], frame[1], frame[2]
    wx, wy, wz = v[0] - o[0], v[1] - o[1], v[2] - o[2]
    return (
        wx * n[0] + wy * n[1] + wz * n[2],
        wx * g1[0] + wy * g1[1] + wz * g1[2],
        wx * g2[0] + wy * g2[1] + wz * g2[2],
    )


@njit(**INLINE)
def _vertex_face(v, huw, frame, best, p, q, vertex_of_a, one):
    """Candidate: vertex ``v`` with height/barycentrics ``huw`` over the other face."""
    zero = one - one
    h, u, w = huw
    n = frame[0]
    d2 = h * h
    take = frame[4] & (u >= zero) & (w >= zero) & (u + w <= one) & (d2 < best)
    foot = (v[0] - h * n[0], v[1] - h * n[1], v[2] - h * n[2])
    on_a = select(vertex_of_a, v, foot)
    on_b = select(vertex_of_a, foot, v)
    return select(take, d2, best), select(take, on_a, p), select(take, on_b, q)


@njit(**INLINE)
def _crossing(v, w, hv, hw, valid, best, p, q, one):
    """Candidate: segment ``v -> w`` crossing the other face (distance 0)."""
    zero = one - one
    dh = hv[0] - hw[0]
    # Signs, not the product hv·hw: the product underflows to 0 for tiny heights.
    opposite = ((hv[0] <= zero) & (hw[0] >= zero)) | ((hv[0] >= zero) & (hw[0] <= zero))
    crosses = valid & opposite & (dh != zero)
    t = min(max(hv[0] / select(dh != zero, dh, one), zero), one)
    u = hv[1] + t * (hw[1] - hv[1])
    s = hv[2] + t * (hw[2] - hv[2])
    x = (v[0] + t * (w[0] - v[0]), v[1] + t * (w[1] - v[1]), v[2] + t * (w[2] - v[2]))
    take = crosses & (u >= zero) & (s >= zero) & (u + s <= one)
    return select(take, zero, best), select(take, x, p), select(take, x, q)


@njit(**INLINE)
def exact_pair(a0, a1, a2, fa, b0, b1, b2, fb, one):
    """Exact distance between triangles ``(a0, a1, a2)`` and ``(b0, b1, b2)``.

    Vertices are ``(x, y, z)`` tuples in a pair-local frame; ``fa``, ``fb`` their
    :func:`triangle_frame` tuples. Returns ``(d2, p, q)``: squared distance,
    closest point on A, closest point on B (``p == q`` at a crossing).
    """
    zero = one - one
    ea1 = (a1[0] - a0[0], a1[1] - a0[1], a1[2] - a0[2])
    ea2 = (a2[0] - a0[0], a2[1] - a0[1], a2[2] - a0[2])
    ea3 = (a2[0] - a1[0], a2[1] - a1[1], a2[2] - a1[2])
    eb1 = (b1[0] - b0[0], b1[1] - b0[1], b1[2] - b0[2])
    eb2 = (b2[0] - b0[0], b2[1] - b0[1], b2[2] - b0[2])
    eb3 = (b2[0] - b1[0], b2[1] - b1[1], b2[2] - b1[2])

    # 9 edge-edge candidates (edges v0->v1, v1->v2, v0->v2 of each).
    best, p, q = segment_segment(a0, ea1, b0, eb1, one)
    d2, pc, qc = segment_segment(a0, ea1, b1, eb3, one)
    best, p, q = select(d2 < best, (d2, pc, qc), (best, p, q))
    d2, pc, qc = segment_segment(a0, ea1, b0, eb2, one)
    best, p, q = select(d2 < best, (d2, pc, qc), (best, p, q))
    d2, pc, qc = segment_segment(a1, ea3, b0, eb1, one)
    best, p, q = select(d2 < best, (d2, pc, qc), (best, p, q))
    d2, pc, qc = segment_segment(a1, ea3, b1, eb3, one)
    best, p, q = select(d2 < best, (d2, pc, qc), (best, p, q))
    d2, pc, qc = segment_segment(a1, ea3, b0, eb2, one)
    best, p, q = select(d2 < best, (d2, pc, qc), (best, p, q))
    d2, pc, qc = segment_segment(a0, ea2, b0, eb1, one)
    best, p, q = select(d2 < best, (d2, pc, qc), (best, p, q))
    d2, pc, qc = segment_segment(a0, ea2, b1, eb3, one)
    best, p, q = select(d2 < best, (d2, pc, qc), (best, p, q))
    d2, pc, qc = segment_segment(a0, ea2, b0, eb2, one)
    best, p, q = select(d2 < best, (d2, pc, qc), (best, p, q))

    # Heights and barycentrics of B's vertices over A, and of A's over B.
    hb0, hb1, hb2 = _height(b0, a0, fa), _height(b1, a0, fa), _height(b2, a0, fa)
    ha0, ha1, ha2 = _height(a0, b0, fb), _height(a1, b0, fb), _height(a2, b0, fb)

    # 6 vertex-face candidates.
    best, p, q = _vertex_face(b0, hb0, fa, best, p, q, False, one)
    best, p, q = _vertex_face(b1, hb1, fa, best, p, q, False, one)
    best, p, q = _vertex_face(b2, hb2, fa, best, p, q, False, one)
    best, p, q = _vertex_face(a0, ha0, fb, best, p, q, True, one)
    best, p, q = _vertex_face(a1, ha1, fb, best, p, q, True, one)
    best, p, q = _vertex_face(a2, ha2, fb, best, p, q, True, one)

    # 6 edge-face crossings.
    va, vb = fa[4], fb[4]
    best, p, q = _crossing(b0, b1, hb0, hb1, va, best, p, q, one)
    best, p, q = _crossing(b1, b2, hb1, hb2, va, best, p, q, one)
    best, p, q = _crossing(b0, b2, hb0, hb2, va, best, p, q, one)
    best, p, q = _crossing(a0, a1, ha0, ha1, vb, best, p, q, one)
    best, p, q = _crossing(a1, a2, ha1, ha2, vb, best, p, q, one)
    best, p, q = _crossing(a0, a2, ha0, ha2, vb, best, p, q, one)
    best = max(best, zero)
    return best, p, q
