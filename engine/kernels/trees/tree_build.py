"""Surrogate-tree construction kernels (host side: :func:`engine.trees.build.build_tree`).

The build works a whole tree level per call, never Python work per node:

* :func:`split_nodes` — seeded k-means (k-means++ seeding, Lloyd iterations) on the
  triangle centroids of each node in a range, and a stable counting sort that makes each
  node's groups contiguous in the next face order.
* :func:`surrogate_nodes` — for each group in a range: its covered vertices, the initial
  triangle (:func:`enclosing_triangle`), the Appendix-A fit
  (:func:`engine.kernels.trees.surrogate_fit.minimise_sampled`) and the exact conservative ε.

Randomness comes from a counter-based generator (SplitMix64) keyed on the seed and the
node's index in the finished tree, so a tree depends on its inputs and seed only, never
on how the level's nodes were split between threads.

A group with more than ``2 · sample`` covered vertices is fitted on a weighted sample of
them: the ``sample`` farthest from the current triangle (weight 1) and ``sample`` drawn at
random from the rest (weight (m − sample) / sample); likewise its vertex–triangle pairs
when there are more than ``2 · pair_sample``. Each soft maximum stays a weighted mean over
the whole group; the sample is redrawn around the current triangle ``SAMPLE_ROUNDS``
times. The ε written is always exact: the largest distance of every covered vertex from
the chosen triangle.
"""

import numpy as np
from numba import njit

from engine.kernels.jit import JIT
from engine.kernels.trees.surrogate_fit import closest_weights_xyz, full_pairs, minimise_sampled

ORIENTATIONS = 24
"""Orientations of the enclosing equilateral triangle tried (over 120°)."""
SAMPLE_ROUNDS = 3
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_FIT_STREAM = np.uint64(0xD1B54A32D192ED03)


# ---------------------------------------------------------------------- random numbers
@njit(**JIT)
def _mix(z):
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


@njit(**JIT)
def _uniform(state, counter):
    """A float64 in [0, 1): the ``counter``-th draw of the stream ``state`` (uint64)."""
    z = _mix(state + _GOLDEN * np.uint64(counter + 1))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(**JIT)
def _stream(seed, node):
    return _mix(np.uint64(seed) * _GOLDEN + np.uint64(node) + np.uint64(1))


# ---------------------------------------------------------------------- k-means
@njit(**JIT)
def _kmeans(points, k, iterations, state, label):
    """Cluster ``points (m, 3)`` float64 into at most ``k`` groups; writes ``label (m,)``
    int64 with the non-empty groups numbered 0, 1, … in cluster order; returns their count.

    k-means++ seeding from the points, then Lloyd iterations (stopping early at a fixed
    point); an emptied cluster is re-seeded with the point farthest from its centre.
    Coincident points that k-means cannot separate are split evenly by index.
    """
    m = points.shape[0]
    draws = 0
    centres = np.empty((k, 3))
    d2 = np.empty(m)
    first = min(int(_uniform(state, draws) * m), m - 1)
    draws += 1
    for c in range(3):
        centres[0, c] = points[first, c]
    for i in range(m):
        d2[i] = _dist2(points, i, centres, 0)
    for j in range(1, k):
        total = 0.0
        for i in range(m):
            total += d2[i]
        pick = m - 1
        if total > 0.0:
            target = _uniform(state, draws) * total
            acc = 0.0
            for i in range(m):
                acc += d2[i]
                if acc > target:
                    pick = i
                    break
        else:
            pick = min(int(_uniform(state, draws) * m), m - 1)
        draws += 1
        for c in range(3):
            centres[j, c] = points[pick, c]
        for i in range(m):
            d2[i] = min(d2[i], _dist2(points, i, centres, j))
    sums = np.empty((k, 3))
    sizes = np.empty(k, np.int64)
    label[:] = -1
    for _ in range(iterations):
        changed = _assign(points, centres, label, d2)
        sums[:] = 0.0
        sizes[:] = 0
        for i in range(m):
            sizes[label[i]] += 1
            for c in range(3):
                sums[label[i], c] += points[i, c]
        empty = False
        for j in range(k):
            if sizes[j] > 0:
                for c in range(3):
                    centres[j, c] = sums[j, c] / sizes[j]
            else:
                empty = True
                far = 0
                for i in range(1, m):
                    if d2[i] > d2[far]:
                        far = i
                for c in range(3):
                    centres[j, c] = points[far, c]
                label[far] = j
                d2[far] = 0.0
        if not changed and not empty:
            break
    _assign(points, centres, label, d2)
    remap = np.full(k, -1, np.int64)
    for i in range(m):
        remap[label[i]] = 0
    groups = 0
    for j in range(k):
        if remap[j] == 0:
            remap[j] = groups
            groups += 1
    if groups < 2:  # k cannot separate the points: split evenly by index (array_split)
        groups = min(k, m)
        base, extra = m // groups, m % groups
        i = 0
        for j in range(groups):
            for _ in range(base + (1 if j < extra else 0)):
                label[i] = j
                i += 1
        return groups
    for i in range(m):
        label[i] = remap[label[i]]
    return groups


@njit(**JIT)
def _dist2(points, i, centres, j):
    return (
        (points[i, 0] - centres[j, 0]) ** 2
        + (points[i, 1] - centres[j, 1]) ** 2
        + (points[i, 2] - centres[j, 2]) ** 2
    )


@njit(**JIT)
def _assign(points, centres, label, d2):
    """Nearest centre of each point (first on ties) into ``label``; its squared distance
    into ``d2``; returns whether any label changed."""
    changed = False
    for i in range(points.shape[0]):
        best, best_d = 0, _dist2(points, i, centres, 0)
        for j in range(1, centres.shape[0]):
            d = _dist2(points, i, centres, j)
            if d < best_d:
                best, best_d = j, d
        if label[i] != best:
            changed = True
            label[i] = best
        d2[i] = best_d
    return changed


@njit(**JIT)
def split_nodes(
    centroids, order, starts, counts, node_ids, k, iterations, seed, lo, hi, order_next, groups
):
    """k-means split of the nodes ``lo … hi − 1`` of a level.

    Parameters
    ----------
    centroids : (F, 3) float64 — triangle centroids
    order : (F,) int64 — faces in node order; node i owns ``order[starts[i]:starts[i] + counts[i]]``
    starts, counts, node_ids : (n,) int64 — segments and tree indices of the level's nodes
    k, iterations, seed : int — groups per split, Lloyd iterations, tree seed
    order_next : (F,) int64 — written: each node's faces, its groups contiguous in group
        order, faces in ``order``'s order within a group (a stable counting sort)
    groups : (n, k) int64 — written: the size of each non-empty group, zeros after them
    """
    for i in range(lo, hi):
        start, m = starts[i], counts[i]
        points = np.empty((m, 3))
        for a in range(m):
            for c in range(3):
                points[a, c] = centroids[order[start + a], c]
        label = np.empty(m, np.int64)
        n_groups = _kmeans(points, k, iterations, _stream(seed, node_ids[i]), label)
        groups[i, :] = 0
        for a in range(m):
            groups[i, label[a]] += 1
        offset = np.zeros(n_groups, np.int64)
        for j in range(1, n_groups):
            offset[j] = offset[j - 1] + groups[i, j - 1]
        for a in range(m):
            order_next[start + offset[label[a]]] = order[start + a]
            offset[label[a]] += 1


# ---------------------------------------------------------------------- the initial triangle
@njit(**JIT)
def _symmetric_eigen(a):
    """Eigenvalues ``(3,)`` (descending) and eigenvectors ``(3, 3)`` (rows) of the symmetric
    ``a (3, 3)`` float64, by cyclic Jacobi rotations."""
    m = a.copy()
    v = np.eye(3)
    for _ in range(50):
        off = m[0, 1] ** 2 + m[0, 2] ** 2 + m[1, 2] ** 2
        scale = m[0, 0] ** 2 + m[1, 1] ** 2 + m[2, 2] ** 2
        if not off > 1e-30 * scale:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if m[p, q] == 0.0:
                continue
            theta = (m[q, q] - m[p, p]) / (2.0 * m[p, q])
            t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
            cos = 1.0 / np.sqrt(t * t + 1.0)
            sin = t * cos
            for r in range(3):  # m ← Jᵀ m J
                mrp, mrq = m[r, p], m[r, q]
                m[r, p] = cos * mrp - sin * mrq
                m[r, q] = sin * mrp + cos * mrq
            for r in range(3):
                mpr, mqr = m[p, r], m[q, r]
                m[p, r] = cos * mpr - sin * mqr
                m[q, r] = sin * mpr + cos * mqr
            for r in range(3):  # columns of v are the eigenvectors
                vrp, vrq = v[r, p], v[r, q]
                v[r, p] = cos * vrp - sin * vrq
                v[r, q] = sin * vrp + cos * vrq
    values = np.array([m[0, 0], m[1, 1], m[2, 2]])
    rank = np.argsort(-values, kind="mergesort")
    vectors = np.empty((3, 3))
    for i in range(3):
        for c in range(3):
            vectors[i, c] = v[c, rank[i]]
    return values[rank], vectors


@njit(**JIT)
def enclosing_triangle(points, summed_normal, out):
    """Smallest enclosing equilateral triangle of ``points (m, 3)`` float64 in their
    mid-height PCA plane, over :data:`ORIENTATIONS` orientations; written to ``out (3, 3)``
    and wound so that its normal agrees with ``summed_normal (3,)`` (the covered faces'
    summed area normal)."""
    m = points.shape[0]
    centre = np.zeros(3)
    for i in range(m):
        for c in range(3):
            centre[c] += points[i, c]
    centre /= m
    cov = np.zeros((3, 3))
    for i in range(m):
        for r in range(3):
            for c in range(3):
                cov[r, c] += (points[i, r] - centre[r]) * (points[i, c] - centre[c])
    _, axes = _symmetric_eigen(cov)
    u = axes[0].copy()
    v = axes[1].copy()
    normal = np.array(
        [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
    )
    facing = normal[0] * summed_normal[0] + normal[1] * summed_normal[1]
    if facing + normal[2] * summed_normal[2] < 0:
        normal = -normal
        v = -v
    low, high = np.inf, -np.inf
    for i in range(m):
        h = 0.0
        for c in range(3):
            h += (points[i, c] - centre[c]) * normal[c]
        low, high = min(low, h), max(high, h)
    for c in range(3):
        centre[c] += normal[c] * (high + low) / 2
    flat = np.empty((m, 2))
    for i in range(m):
        x = y = 0.0
        for c in range(3):
            x += (points[i, c] - centre[c]) * u[c]
            y += (points[i, c] - centre[c]) * v[c]
        flat[i, 0], flat[i, 1] = x, y
    best_total, best = np.inf, 0
    support = np.empty(3)
    best_support = np.empty(3)
    for o in range(ORIENTATIONS):
        total = 0.0
        for s in range(3):
            angle = o * (2 * np.pi / 3) / ORIENTATIONS + s * 2 * np.pi / 3
            dx, dy = np.cos(angle), np.sin(angle)
            top = -np.inf
            for i in range(m):
                top = max(top, dx * flat[i, 0] + dy * flat[i, 1])
            support[s] = top
            total += top
        if total < best_total:
            best_total, best = total, o
            best_support[:] = support
    dirs = np.empty((3, 2))
    for s in range(3):
        angle = best * (2 * np.pi / 3) / ORIENTATIONS + s * 2 * np.pi / 3
        dirs[s, 0], dirs[s, 1] = np.cos(angle), np.sin(angle)
    for corner, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):  # opposite side `corner`
        det = dirs[i, 0] * dirs[j, 1] - dirs[i, 1] * dirs[j, 0]
        x = (best_support[i] * dirs[j, 1] - dirs[i, 1] * best_support[j]) / det
        y = (dirs[i, 0] * best_support[j] - best_support[i] * dirs[j, 0]) / det
        for c in range(3):
            out[corner, c] = centre[c] + x * u[c] + y * v[c]
    e1 = out[1] - out[0]
    e2 = out[2] - out[0]
    wind = (
        (e1[1] * e2[2] - e1[2] * e2[1]) * normal[0]
        + (e1[2] * e2[0] - e1[0] * e2[2]) * normal[1]
        + (e1[0] * e2[1] - e1[1] * e2[0]) * normal[2]
    )
    if wind < 0:
        for c in range(3):
            out[1, c], out[2, c] = out[2, c], out[1, c]


# ---------------------------------------------------------------------- surrogates
@njit(**JIT)
def _point_distance(points, i, tri):
    """Distance from ``points[i]`` to the triangle ``tri (3, 3)``."""
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    a, b, c = closest_weights_xyz(
        px, py, pz,
        tri[0, 0], tri[0, 1], tri[0, 2], tri[1, 0], tri[1, 1], tri[1, 2],
        tri[2, 0], tri[2, 1], tri[2, 2],
    )  # fmt: skip
    dx = px - a * tri[0, 0] - b * tri[1, 0] - c * tri[2, 0]
    dy = py - a * tri[0, 1] - b * tri[1, 1] - c * tri[2, 1]
    dz = pz - a * tri[0, 2] - b * tri[1, 2] - c * tri[2, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(**JIT)
def largest_distance(points, tri):
    """Largest distance of ``points (m, 3)`` from ``tri (3, 3)``: the exact ε of a
    surrogate (distance to a triangle is convex, so a covered triangle's farthest point
    is one of its vertices)."""
    top = 0.0
    for i in range(points.shape[0]):
        top = max(top, _point_distance(points, i, tri))
    return top


@njit(**JIT)
def region_volume(tri, epsilon):
    """Volume of the ε-region of ``tri (3, 3)``: 2·area·ε + perimeter·πε²/2 + 4/3·πε³."""
    e1 = tri[1] - tri[0]
    e2 = tri[2] - tri[0]
    cx = e1[1] * e2[2] - e1[2] * e2[1]
    cy = e1[2] * e2[0] - e1[0] * e2[2]
    cz = e1[0] * e2[1] - e1[1] * e2[0]
    area = 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)
    perimeter = 0.0
    for k in range(3):
        d = tri[k] - tri[(k + 1) % 3]
        perimeter += np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    return 2 * area * epsilon + perimeter * np.pi * epsilon**2 / 2 + 4.0 / 3.0 * np.pi * epsilon**3


@njit(**JIT)
def _fit(
    points, tris, initial, params, iterations, history, tolerance, sample, pair_sample, state, out
):
    """The Appendix-A fit from ``initial (3, 3)`` into ``out (3, 3)`` (``initial`` when the
    fit is not finite), in the group's normalised frame; large groups on an active set."""
    m, t = points.shape[0], tris.shape[0]
    centre = np.zeros(3)
    for i in range(m):
        centre += points[i]
    centre /= m
    radius = 0.0
    for i in range(m):
        radius = max(radius, np.sqrt(((points[i] - centre) ** 2).sum()))
    out[:] = initial
    if not radius > 0.0:
        return
    local = (points - centre) / radius
    local_tris = np.empty((t, 3, 3))
    for j in range(t):
        for k in range(3):
            local_tris[j, k] = (tris[j, k] - centre) / radius
    x = (initial - centre) / radius
    all_points, all_pairs = m <= 2 * sample, 3 * t <= 2 * pair_sample
    if all_points:
        chosen, w_chosen = np.arange(m), np.ones(m)
    if all_pairs:
        pair_vertex, pair_tri = full_pairs(t)
        w_pairs = np.ones(3 * t)
    if all_points and all_pairs:
        rounds = 1
    else:
        rounds = SAMPLE_ROUNDS
        far = np.empty(m)
        pair_far = np.empty(3 * t)
    for round_ in range(rounds):
        if not all_points:
            for i in range(m):
                far[i] = -_point_distance(local, i, x)
            chosen, w_chosen = _weighted_sample(far, sample, state, 4 * round_)
        if not all_pairs:
            for k in range(3):
                for j in range(t):
                    pair_far[k * t + j] = -_point_distance(x, k, local_tris[j])
            pairs, w_pairs = _weighted_sample(pair_far, pair_sample, state, 4 * round_ + 2)
            pair_vertex, pair_tri = pairs // t, pairs % t
        minimise_sampled(
            x, local[chosen], w_chosen, local_tris, pair_vertex, pair_tri, w_pairs,
            params, iterations, history, tolerance,
        )  # fmt: skip
    if np.isfinite(x).all():
        for k in range(3):
            out[k] = centre + radius * x[k]


@njit(**JIT)
def _weighted_sample(key, size, state, stream):
    """Indices and weights of a sample standing for all ``n`` values: the ``size`` smallest
    ``key`` (weight 1 each) and ``size`` uniform draws with replacement from the rest
    (weight (n − size) / size each); ``stream`` selects the draws of ``state``."""
    n = key.size
    ranked = np.argsort(key, kind="mergesort")
    index = np.empty(2 * size, np.int64)
    weight = np.empty(2 * size)
    index[:size] = ranked[:size]
    weight[:size] = 1.0
    rest = n - size
    for i in range(size):
        pick = size + min(int(_uniform(_mix(state + np.uint64(stream)), i) * rest), rest - 1)
        index[size + i] = ranked[pick]
        weight[size + i] = rest / size
    return index, weight


@njit(**JIT)
def surrogate_nodes(
    vertices, faces, tris, order, starts, counts, node_ids, leaf_epsilon, params, fit,
    iterations, history, tolerance, sample, pair_sample, seed, lo, hi, mark, out_tris, out_eps,
):  # fmt: skip
    """Surrogate triangle and conservative ε of the groups ``lo … hi − 1`` of a level.

    Parameters
    ----------
    vertices : (V, 3) float64; faces : (F, 3) int32; tris : (F, 3, 3) float64
    order : (F,) int64 — group i covers faces ``order[starts[i]:starts[i] + counts[i]]``
    starts, counts, node_ids : (n,) int64 — segments and tree indices of the groups
    leaf_epsilon : float — ε of the original triangles; seed : int — the tree's seed
    params : (6,) float64 — the functional's parameters; ``fit`` False keeps the initial
        triangle; iterations, history, tolerance — L-BFGS;
        sample, pair_sample — weighted-sample sizes (module docstring)
    mark : (V,) int64 — scratch of this call's thread: zeros, or as an earlier call left it
    out_tris : (n, 3, 3) float64, out_eps : (n,) float64 — written at rows lo … hi − 1

    A one-face group's surrogate is that face with the leaf ε. Otherwise the fitted
    triangle replaces the initial one only if its ε-region, with its exact ε, is not larger.
    """
    initial = np.empty((3, 3))
    fitted = np.empty((3, 3))
    for g in range(lo, hi):
        start, count = starts[g], counts[g]
        if count == 1:
            out_tris[g] = tris[order[start]]
            out_eps[g] = leaf_epsilon
            continue
        stamp = -2 - 2 * node_ids[g]  # and stamp − 1: this group's, no other's
        n_points = 0
        for a in range(count):
            for corner in range(3):
                vertex = faces[order[start + a], corner]
                if mark[vertex] != stamp:
                    mark[vertex] = stamp
                    n_points += 1
        points = np.empty((n_points, 3))
        group = np.empty((count, 3, 3))
        summed = np.zeros(3)
        n_points = 0
        for a in range(count):
            f = order[start + a]
            group[a] = tris[f]
            e1 = tris[f, 1] - tris[f, 0]
            e2 = tris[f, 2] - tris[f, 0]
            summed[0] += e1[1] * e2[2] - e1[2] * e2[1]
            summed[1] += e1[2] * e2[0] - e1[0] * e2[2]
            summed[2] += e1[0] * e2[1] - e1[1] * e2[0]
            for corner in range(3):
                vertex = faces[f, corner]
                if mark[vertex] == stamp:
                    mark[vertex] = stamp - 1  # taken
                    points[n_points] = vertices[vertex]
                    n_points += 1
        enclosing_triangle(points, summed, initial)
        eps = largest_distance(points, initial)
        out_tris[g] = initial
        if fit:
            state = _stream(seed, node_ids[g]) ^ _FIT_STREAM  # not k-means's draws
            _fit(
                points, group, initial, params, iterations, history, tolerance, sample,
                pair_sample, state, fitted,
            )  # fmt: skip
            fitted_eps = largest_distance(points, fitted)
            if region_volume(fitted, fitted_eps) <= region_volume(initial, eps):
                out_tris[g] = fitted
                eps = fitted_eps
        out_eps[g] = eps + leaf_epsilon
