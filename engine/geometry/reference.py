"""Slow, obviously-correct reference geometry for testing the distance kernels.

Everything here is plain numpy and Python control flow, one pair at a time,
written from the textbook case analyses (Ericson, *Real-Time Collision
Detection*, 2005) and independently of :mod:`engine.kernels`:

* :func:`closest_point_on_triangle_naive` — §5.1.5, the Voronoi-region walk
  (vertex regions, then edge regions, then the face), with an explicit branch
  for degenerate (zero-area) triangles;
* :func:`segment_segment_naive` — §5.1.9, with its degenerate cases (either or
  both segments a point) and the parallel case;
* :func:`segment_triangle_intersection_naive` — plane crossing and a
  barycentric inside test; a segment lying in the triangle's plane is tested
  against the triangle's area and edges;
* :func:`triangle_distance_naive` — zero when an edge of either triangle meets
  the other triangle, otherwise the minimum over the 6 vertex–triangle and the
  9 edge–edge distances. (Two disjoint triangles have a closest pair of points
  in which one is a vertex or both lie on edges, so the 15 candidates contain
  the minimum; two intersecting triangles always have an edge of one meeting the
  other.)

Nothing here is fast; it is an oracle for the tests, never for production.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np

__all__ = [
    "closest_point_on_triangle_naive",
    "point_triangle_distance_naive",
    "segment_segment_naive",
    "segment_triangle_intersection_naive",
    "triangle_distance_naive",
    "triangle_distances_naive",
    "triangles_intersect_naive",
]

_EDGES = ((0, 1), (1, 2), (2, 0))
_SLIVER = 1e-6  # sin² of the angle at a below which the closest point is found exactly


def _vec(x, shape: tuple[int, ...], name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cross product of two (3,) vectors (``np.cross`` is slow on tiny arrays)."""
    return np.array(
        [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
    )


def _clamp01(x: float) -> float:
    if x < 0.0:
        return 0.0
    if x > 1.0:
        return 1.0
    return x


def _closest_on_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Closest point to ``p`` on segment ``a b`` (Ericson §5.1.2); ``a`` if it is a point."""
    ab = b - a
    denom = float(ab @ ab)
    if denom == 0.0:
        return a.copy()
    t = _clamp01(float((p - a) @ ab) / denom)
    return a + t * ab


def closest_point_on_triangle_naive(p, tri) -> np.ndarray:
    """Closest point of a triangle to a point (Ericson §5.1.5).

    Parameters
    ----------
    p : (3,) float64
        The query point.
    tri : (3, 3) float64
        Triangle vertices ``a, b, c`` as rows.

    Returns
    -------
    (3,) float64
        The point of the (closed, solid) triangle nearest to ``p``.

    Notes
    -----
    Regions are tested in the textbook order: vertex ``a``, vertex ``b``, edge
    ``ab``, vertex ``c``, edge ``ac``, edge ``bc``, and finally the face, whose
    point is the orthogonal projection on the plane (Ericson writes it with the
    barycentric coordinates ``(va, vb, vc) / (va + vb + vc)``, which lose accuracy
    for slivers).
    A zero-area triangle (all three region denominators vanish) is the union of
    its edges, so its closest point is the nearest of the three edge points.
    A nearly collinear triangle (sin² of its angle at ``a`` below 1e-6) is solved in
    exact rational arithmetic: in floating point its region tests cancel.
    """
    p = _vec(p, (3,), "p")
    tri = _vec(tri, (3, 3), "tri")
    a, b, c = tri
    ab, ac, ap = b - a, c - a, p - a

    n = _cross(ab, ac)
    if 0.0 < float(n @ n) <= _SLIVER * float(ab @ ab) * float(ac @ ac):
        return _closest_point_exact(p, tri)
    if float(n @ n) == 0.0:
        # Degenerate triangle: a segment or a point, i.e. the union of its edges.
        cands = [_closest_on_segment(p, tri[i], tri[j]) for i, j in _EDGES]
        return min(cands, key=lambda x: float((x - p) @ (x - p)))

    d1, d2 = float(ab @ ap), float(ac @ ap)
    if d1 <= 0.0 and d2 <= 0.0:
        return a.copy()  # vertex region a

    bp = p - b
    d3, d4 = float(ab @ bp), float(ac @ bp)
    if d3 >= 0.0 and d4 <= d3:
        return b.copy()  # vertex region b

    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return a + v * ab  # edge region ab

    cp = p - c
    d5, d6 = float(ab @ cp), float(ac @ cp)
    if d6 >= 0.0 and d5 <= d6:
        return c.copy()  # vertex region c

    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return a + w * ac  # edge region ac

    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return b + w * (c - b)  # edge region bc

    # Face region. Ericson returns a + ab vb / (va + vb + vc) + ac vc / (va + vb + vc),
    # which is the orthogonal projection of p on the plane; for slivers va, vb and vc
    # are differences of nearly equal products, so the projection is computed directly.
    return p - (float(ap @ n) / float(n @ n)) * n


def _closest_point_exact(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """:func:`closest_point_on_triangle_naive` for a non-degenerate triangle, in exact
    rational arithmetic (Ericson's region tests and barycentric face point), rounded
    to float64 at the end."""
    q = [Fraction(float(x)) for x in p]
    a, b, c = ([Fraction(float(x)) for x in v] for v in tri)

    def sub(u, v):
        return [u[0] - v[0], u[1] - v[1], u[2] - v[2]]

    def dot(u, v):
        return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]

    def point(origin, weights):  # origin + Σ w_k e_k
        return np.array([float(origin[i] + sum(w * e[i] for w, e in weights)) for i in range(3)])

    ab, ac, ap, bp, cp = sub(b, a), sub(c, a), sub(q, a), sub(q, b), sub(q, c)
    d1, d2, d3, d4, d5, d6 = (
        dot(ab, ap),
        dot(ac, ap),
        dot(ab, bp),
        dot(ac, bp),
        dot(ab, cp),
        dot(ac, cp),
    )
    if d1 <= 0 and d2 <= 0:
        return point(a, [])
    if d3 >= 0 and d4 <= d3:
        return point(b, [])
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return point(a, [(d1 / (d1 - d3), ab)])
    if d6 >= 0 and d5 <= d6:
        return point(c, [])
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return point(a, [(d2 / (d2 - d6), ac)])
    va = d3 * d6 - d5 * d4
    if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        return point(b, [((d4 - d3) / ((d4 - d3) + (d5 - d6)), sub(c, b))])
    total = va + vb + vc
    return point(a, [(vb / total, ab), (vc / total, ac)])


def point_triangle_distance_naive(p, tri) -> float:
    """Distance from a point ``p (3,)`` to a triangle ``tri (3, 3)`` (float64)."""
    p = _vec(p, (3,), "p")
    x = closest_point_on_triangle_naive(p, tri)
    return float(np.linalg.norm(p - x))


def segment_segment_naive(p0, p1, q0, q1) -> tuple[float, np.ndarray, np.ndarray]:
    """Closest points of segments ``p0 p1`` and ``q0 q1`` (Ericson §5.1.9).

    Parameters
    ----------
    p0, p1 : (3,) float64
        End points of the first segment (may coincide).
    q0, q1 : (3,) float64
        End points of the second segment (may coincide).

    Returns
    -------
    distance : float
    point_p : (3,) float64
        Closest point on the first segment, ``p0 + s (p1 - p0)``, ``0 ≤ s ≤ 1``.
    point_q : (3,) float64
        Closest point on the second segment, ``q0 + t (q1 - q0)``, ``0 ≤ t ≤ 1``.
    """
    p0, p1 = _vec(p0, (3,), "p0"), _vec(p1, (3,), "p1")
    q0, q1 = _vec(q0, (3,), "q0"), _vec(q1, (3,), "q1")
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)

    if a == 0.0 and e == 0.0:
        s = t = 0.0  # both segments are points
    elif a == 0.0:
        s, t = 0.0, _clamp01(f / e)  # first segment is a point
    else:
        c = float(d1 @ r)
        if e == 0.0:
            s, t = _clamp01(-c / a), 0.0  # second segment is a point
        else:
            b = float(d1 @ d2)
            # Ericson's denom = a e - b^2 and numerator b f - c e, evaluated through
            # Lagrange's identity as |d1 x d2|^2 and ((d1 x d2) x d2) . r: the same
            # numbers, but without the cancellation that makes a e - b^2 pure
            # rounding noise for nearly parallel segments.
            m = _cross(d1, d2)
            denom = float(m @ m)
            # Non-parallel: the closest point of the infinite lines, clamped.
            # Parallel: any s works; take s = 0 and let t decide.
            s = _clamp01(float(_cross(m, d2) @ r) / denom) if denom != 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t, s = 0.0, _clamp01(-c / a)
            elif t > 1.0:
                t, s = 1.0, _clamp01((b - c) / a)

    cp = p0 + s * d1
    cq = q0 + t * d2
    return float(np.linalg.norm(cp - cq)), cp, cq


def segment_triangle_intersection_naive(p0, p1, tri) -> np.ndarray | None:
    """A point where segment ``p0 p1`` meets triangle ``tri``, or None.

    Parameters
    ----------
    p0, p1 : (3,) float64
        End points of the segment.
    tri : (3, 3) float64
        Triangle vertices as rows.

    Returns
    -------
    (3,) float64 or None
        A common point of the segment and the (closed, solid) triangle.

    Notes
    -----
    Signed heights ``h0, h1`` of the end points over the triangle's plane decide:
    the same strict sign means no crossing; otherwise the crossing point
    ``p0 + h0 / (h0 - h1) (p1 - p0)`` is tested against the triangle with
    barycentric coordinates (signed sub-triangle areas, all ``≥ 0``). A segment
    in the plane (``h0 = h1 = 0``, or a zero-area triangle) meets the triangle
    when an end point is inside it or it meets one of its edges (closest-point
    distance at most ``1e-12`` of the extent).
    """
    p0, p1 = _vec(p0, (3,), "p0"), _vec(p1, (3,), "p1")
    tri = _vec(tri, (3, 3), "tri")
    a, b, c = tri
    n = _cross(b - a, c - a)
    h0, h1 = float(n @ (p0 - a)), float(n @ (p1 - a))

    if (h0 > 0.0 and h1 > 0.0) or (h0 < 0.0 and h1 < 0.0):
        return None

    if h0 == h1:  # both zero: the segment lies in the plane (or the triangle is flat)
        scale = max(float(np.abs(np.vstack([tri, p0, p1]) - a).max()), 1e-300)
        tol = 1e-12 * scale
        for x in (p0, p1):
            if point_triangle_distance_naive(x, tri) <= tol:
                return x.copy()
        for i, j in _EDGES:
            d, cp, cq = segment_segment_naive(p0, p1, tri[i], tri[j])
            if d <= tol:
                return cp
        return None

    x = p0 + (h0 / (h0 - h1)) * (p1 - p0)
    # Barycentric coordinates of x: signed areas of the sub-triangles opposite
    # each vertex, measured along the normal.
    u = float(n @ _cross(b - x, c - x))
    v = float(n @ _cross(c - x, a - x))
    w = float(n @ _cross(a - x, b - x))
    if u >= 0.0 and v >= 0.0 and w >= 0.0:
        return x
    return None


def triangles_intersect_naive(a, b) -> bool:
    """Whether triangles ``a (3, 3)`` and ``b (3, 3)`` (float64) share a point.

    True when one of the six edges meets the other triangle, which covers every
    intersection of non-coplanar triangles. Coplanar pairs (exactly, in floating
    point: zero heights) are covered too, containment included, since the edges
    of a contained triangle lie in the other. Pairs that are coplanar only up to
    rounding may be missed; :func:`triangle_distance_naive` then finds a
    distance at rounding level.
    """
    return _edge_crossing(_vec(a, (3, 3), "a"), _vec(b, (3, 3), "b")) is not None


def _edge_crossing(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    for tri, other in ((a, b), (b, a)):
        for i, j in _EDGES:
            x = segment_triangle_intersection_naive(tri[i], tri[j], other)
            if x is not None:
                return x
    return None


def triangle_distance_naive(a, b) -> tuple[float, np.ndarray, np.ndarray]:
    """Distance between two triangles and a closest pair of points.

    Parameters
    ----------
    a : (3, 3) float64
        Vertices of triangle A as rows.
    b : (3, 3) float64
        Vertices of triangle B as rows.

    Returns
    -------
    distance : float
    point_a : (3,) float64
        Closest point on A.
    point_b : (3,) float64
        Closest point on B (equal to ``point_a`` when the triangles meet).

    Notes
    -----
    The work is done relative to ``a[0]`` (a translation, which changes no
    distance) so that far-from-origin inputs lose no precision; the points are
    translated back.
    """
    a = _vec(a, (3, 3), "a")
    b = _vec(b, (3, 3), "b")
    origin = a[0].copy()
    la, lb = a - origin, b - origin

    x = _edge_crossing(la, lb)
    if x is not None:
        return 0.0, x + origin, x + origin

    best = (np.inf, la[0], lb[0])
    for k in range(3):  # vertices of B against A, then of A against B
        pa = closest_point_on_triangle_naive(lb[k], la)
        d = float(np.linalg.norm(pa - lb[k]))
        if d < best[0]:
            best = (d, pa, lb[k])
        pb = closest_point_on_triangle_naive(la[k], lb)
        d = float(np.linalg.norm(la[k] - pb))
        if d < best[0]:
            best = (d, la[k], pb)
    for i, j in _EDGES:  # 9 edge pairs
        for k, m in _EDGES:
            d, pa, pb = segment_segment_naive(la[i], la[j], lb[k], lb[m])
            if d < best[0]:
                best = (d, pa, pb)
    d, pa, pb = best
    return d, pa + origin, pb + origin


def triangle_distances_naive(a, b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`triangle_distance_naive` over paired triangles.

    Parameters
    ----------
    a : (n, 3, 3) float64
    b : (n, 3, 3) float64

    Returns
    -------
    distance : (n,) float64
    point_a : (n, 3) float64
    point_b : (n, 3) float64
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 3 or a.shape[1:] != (3, 3) or b.shape != a.shape:
        raise ValueError(f"a and b must both have shape (n, 3, 3), got {a.shape} and {b.shape}")
    n = len(a)
    distance = np.empty(n)
    point_a = np.empty((n, 3))
    point_b = np.empty((n, 3))
    for t in range(n):
        distance[t], point_a[t], point_b[t] = triangle_distance_naive(a[t], b[t])
    return distance, point_a, point_b
