"""Broad phase: candidate body pairs from bounding spheres, by a hierarchical cell grid.

Bodies are sorted into *levels* by size (the host picks each level's cell ``sizes[b]``,
at least as wide as the boxes of its bodies). A body of level ``g`` gets one *entry* per
cell that its (slightly widened) bounding box overlaps at level ``g`` and at every
coarser level: at most 2 × 2 × 2 cells per level, however large the body. In a
level-``b`` cell, only pairs with a *native* entry (a body of level ``b``) are tested, so
each pair is found at the level of its larger body; of the cells both boxes share, only
the one holding the maximum corner of their lowest cells reports it (the *owner* cell:
the pair passes iff the two entries' 3-bit masks "lowest cell along axis a" cover all
three axes).

Cell lists are a spatial hash: entries are counting-sorted into ``M`` buckets (a power
of two) by ``2 · (hash(level, cell) mod M) + foreign``, so natives come first in a
bucket. Each entry carries a *tag*, the cell's hash with its low 3 bits replaced by the
mask: entries of one bucket are taken for the same cell iff their tags agree above the
mask. Distinct cells pass that test only on a full 64-bit hash collision, which can
repeat a pair (:func:`sort_pairs` drops repeats) but never lose one.

Every kernel is compiled without fast-math: the overlap test
``dx² + dy² + dz² ≤ (r_i + r_j)²`` must round exactly as that float64 expression, and
cell indices must be the same monotone function of position in every kernel (the host
widens each box by a few ulp so rounding never separates spheres that pass the test).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.jit import EXACT_BORROW, JIT

EXACT = {**JIT, "fastmath": False}
EXACT_INLINE = {**EXACT, "inline": "always"}

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_NOT_MASK = np.uint64(~np.uint64(7))


@njit(**EXACT_INLINE)
def _mix(h):
    """splitmix64 finaliser of a uint64."""
    h = (h ^ (h >> np.uint64(30))) * _M1
    h = (h ^ (h >> np.uint64(27))) * _M2
    return h ^ (h >> np.uint64(31))


@njit(**EXACT_INLINE)
def _hash(level, ix, iy, iz):
    """uint64 hash of cell ``(level, ix, iy, iz)``."""
    h = _mix(np.uint64(level) + _GOLDEN)
    h = _mix(h ^ np.uint64(ix))
    h = _mix(h ^ np.uint64(iy))
    return _mix(h ^ np.uint64(iz))


@njit(**EXACT_INLINE)
def _cells(x, reach, origin, size):
    """First and last cell index along one axis of the box ``[x − reach, x + reach]``."""
    lo = np.int64(np.floor((x - reach - origin) / size))
    return lo, np.int64(np.floor((x + reach - origin) / size))


@njit(**EXACT)
def scene_box(centres, radii, low, high, scale):
    """Bounding box of all spheres (``centres (n, 3)``, ``radii (n,)`` float64, n ≥ 1):
    writes its corners ``low, high (3,)`` and each centre's largest absolute coordinate
    ``scale (n,)`` float64."""
    for a in range(3):
        low[a], high[a] = centres[0, a] - radii[0], centres[0, a] + radii[0]
    for i in range(centres.shape[0]):
        scale[i] = 0.0
        for a in range(3):
            low[a] = min(low[a], centres[i, a] - radii[i])
            high[a] = max(high[a], centres[i, a] + radii[i])
            scale[i] = max(scale[i], abs(centres[i, a]))


@njit(**EXACT)
def count_entries(centres, reach, level, sizes, origin, counts):
    """Entries of each body: the cells its box overlaps at its level and every coarser one.

    ``centres (n, 3)``, ``reach (n,)`` (box half-width: radius plus rounding slack) and
    ``origin (3,)`` float64; ``level (n,)`` int64 in ``[0, L)``; ``sizes (L,)`` float64
    cell size per level. Writes ``counts (n,)`` int64.
    """
    for i in range(centres.shape[0]):
        total = 0
        for b in range(level[i], sizes.shape[0]):
            m = 1
            for a in range(3):
                lo, hi = _cells(centres[i, a], reach[i], origin[a], sizes[b])
                m *= hi - lo + 1
            total += m
        counts[i] = total


@njit(**EXACT)
def fill_entries(centres, reach, level, sizes, origin, offsets, buckets, slots, bodies, tags):
    """Write body ``i``'s entries to rows ``offsets[i]:offsets[i + 1]`` (arguments as in
    :func:`count_entries`; ``offsets (n + 1,)`` int64 their prefix sum; ``buckets`` a
    power of two).

    Per entry: ``slots (E,)`` int64, ``2 · (hash mod buckets) + foreign`` (foreign: a
    level coarser than the body's); ``bodies (E,)`` int64; ``tags (E,)`` int64, the hash
    (shifted to 63 bits) with the low 3 bits set to the owner mask.
    """
    low = np.uint64(buckets - 1)
    for i in range(centres.shape[0]):
        e = offsets[i]
        r = reach[i]
        for b in range(level[i], sizes.shape[0]):
            lo0, hi0 = _cells(centres[i, 0], r, origin[0], sizes[b])
            lo1, hi1 = _cells(centres[i, 1], r, origin[1], sizes[b])
            lo2, hi2 = _cells(centres[i, 2], r, origin[2], sizes[b])
            foreign = np.int64(b != level[i])
            for x in range(lo0, hi0 + 1):
                for y in range(lo1, hi1 + 1):
                    for z in range(lo2, hi2 + 1):
                        h = _hash(b, x, y, z)
                        slots[e] = 2 * np.int64(h & low) + foreign
                        bodies[e] = i
                        mask = (x == lo0) + 2 * (y == lo1) + 4 * (z == lo2)
                        tags[e] = np.int64((h >> np.uint64(1)) & _NOT_MASK) + mask
                        e += 1


@njit(**EXACT)
def bucket_sort(slots, bodies, tags, starts, bodies_out, tags_out):
    """Counting sort of the entries by slot (``slots (E,)`` int64 in ``[0, S)``): writes
    ``starts (S + 1,)`` int64 (slot ``s`` holds rows ``starts[s]:starts[s + 1]``) and the
    permuted ``bodies_out (E,)``, ``tags_out (E,)`` int64."""
    starts[:] = 0
    for e in range(slots.shape[0]):
        starts[slots[e] + 1] += 1
    for s in range(1, starts.shape[0]):
        starts[s] += starts[s - 1]
    fill = starts[:-1].copy()
    for e in range(slots.shape[0]):
        k = fill[slots[e]]
        fill[slots[e]] = k + 1
        bodies_out[k] = bodies[e]
        tags_out[k] = tags[e]


@njit(**EXACT)
def pair_bounds(starts, bounds):
    """Pairs each bucket may report at most, ``bounds (M,)`` int64: every native entry
    against every later entry of its bucket (``starts (2M + 1,)`` from :func:`bucket_sort`)."""
    for u in range(bounds.shape[0]):
        native = starts[2 * u + 1] - starts[2 * u]
        size = starts[2 * u + 2] - starts[2 * u]
        bounds[u] = native * (size - 1) - native * (native - 1) // 2


@njit(**EXACT)
def bucket_pairs(starts, bodies, tags, centres, radii, fixed, offsets, out, found):
    """Overlapping pairs of every bucket (sorted entries from :func:`bucket_sort`; bucket
    ``u``'s natives are rows ``starts[2u]:starts[2u + 1]``, its foreign entries follow up
    to ``starts[2u + 2]``).

    A pair of bodies (i ≠ j) is reported by its owner cell at the level of its larger
    body, unless both ``fixed (n,)`` bool are set, iff ``dx² + dy² + dz² ≤ (r_i + r_j)²``
    (``centres (n, 3)``, ``radii (n,)`` float64). Bucket ``u`` writes its ``found[u]``
    pairs ``(min, max)`` to rows ``offsets[u]:offsets[u] + found[u]`` of ``out (K, 2)``
    int64 (``offsets (M + 1,)`` int64, the prefix sum of :func:`pair_bounds`).
    """
    for u in range(found.shape[0]):
        k = offsets[u]
        end = starts[2 * u + 2]
        for p in range(starts[2 * u], starts[2 * u + 1]):
            i, tag = bodies[p], tags[p]
            for q in range(p + 1, end):
                t = tags[q]
                if (tag | t) & 7 != 7 or (tag ^ t) >> 3 != 0:
                    continue
                j = bodies[q]
                if j != i and _candidate(centres, radii, fixed, i, j):
                    out[k, 0], out[k, 1] = min(i, j), max(i, j)
                    k += 1
        found[u] = k - offsets[u]


@njit(**EXACT)
def all_pairs(centres, radii, fixed, out):
    """Every pair ``i < j`` whose spheres overlap, unless both ``fixed``, by brute force
    (for a handful of bodies, where the grid's set-up costs more): the test of
    :func:`bucket_pairs`, in lexicographic order, into ``out (≥ n(n − 1)/2, 2)`` int64;
    returns the count."""
    n = radii.shape[0]
    k = 0
    for i in range(n):
        for j in range(i + 1, n):
            if _candidate(centres, radii, fixed, i, j):
                out[k, 0], out[k, 1] = i, j
                k += 1
    return k


@njit(**EXACT)
def filter_pairs(candidates, centres, radii, out):
    """The rows of ``candidates (m, 2)`` int64 (pairs ``i < j``, not both fixed) whose
    spheres overlap now, by the test of :func:`bucket_pairs` in the same float64 order,
    kept in order in ``out (≥ k, 2)`` int64; returns ``k``."""
    k = 0
    for p in range(candidates.shape[0]):
        i, j = candidates[p, 0], candidates[p, 1]
        dx = centres[i, 0] - centres[j, 0]
        dy = centres[i, 1] - centres[j, 1]
        dz = centres[i, 2] - centres[j, 2]
        s = radii[i] + radii[j]
        if dx * dx + dy * dy + dz * dz <= s * s:
            out[k, 0], out[k, 1] = i, j
            k += 1
    return k


@njit(**EXACT)
def within_reach(centres, listed, allowed):
    """Whether every centre ``centres (n, 3)`` float64 lies within ``allowed (n,)`` float64
    (≥ 0; 0: not moved at all) of where it was listed, ``listed (n, 3)`` float64."""
    for i in range(centres.shape[0]):
        dx = centres[i, 0] - listed[i, 0]
        dy = centres[i, 1] - listed[i, 1]
        dz = centres[i, 2] - listed[i, 2]
        if not dx * dx + dy * dy + dz * dz <= allowed[i] * allowed[i]:  # NaN: moved
            return False
    return True


@njit(**EXACT_BORROW)  # spliced in at Numba-IR level, its three arrays' reference counts
def _candidate(centres, radii, fixed, i, j):  # cost 44 µs of all_pairs' 47 µs on 53 bodies
    """Bodies ``i`` and ``j`` are a candidate pair: not both fixed, and
    ``dx² + dy² + dz² ≤ (r_i + r_j)²`` in exactly this float64 order."""
    if fixed[i] and fixed[j]:
        return False
    dx = centres[i, 0] - centres[j, 0]
    dy = centres[i, 1] - centres[j, 1]
    dz = centres[i, 2] - centres[j, 2]
    s = radii[i] + radii[j]
    return dx * dx + dy * dy + dz * dz <= s * s


@njit(**EXACT)
def sort_pairs(pairs, offsets, found, n, out):
    """Rows ``offsets[u]:offsets[u] + found[u]`` of ``pairs (K, 2)`` int64, sorted
    lexicographically and without repeats, into ``out (≥ k, 2)`` int64; returns ``k``.

    Counting sort on the first index (``0 ≤ i < n``), then each run of equal ``i`` sorted.
    """
    first = np.zeros(n + 1, np.int64)
    for u in range(found.shape[0]):
        for k in range(offsets[u], offsets[u] + found[u]):
            first[pairs[k, 0] + 1] += 1
    for i in range(n):
        first[i + 1] += first[i]
    fill = first[:-1].copy()
    second = np.empty(first[n], np.int64)
    for u in range(found.shape[0]):
        for k in range(offsets[u], offsets[u] + found[u]):
            second[fill[pairs[k, 0]]] = pairs[k, 1]
            fill[pairs[k, 0]] += 1
    count = 0
    for i in range(n):
        run = second[first[i] : first[i + 1]]
        if run.shape[0] > 16:
            run.sort()
        else:  # insertion sort: most bodies have a handful of partners
            for m in range(1, run.shape[0]):
                x, a = run[m], m
                while a > 0 and run[a - 1] > x:
                    run[a] = run[a - 1]
                    a -= 1
                run[a] = x
        for m in range(run.shape[0]):
            if m == 0 or run[m] != run[m - 1]:
                out[count, 0], out[count, 1] = i, run[m]
                count += 1
    return count
