"""Vertex welding: a greedy merge of points within a tolerance, on a hashed grid.

Used by :mod:`engine.geometry.repair`, which validates the points and allocates the table."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from engine.kernels.jit import JIT

# IEEE arithmetic, no FMA contraction: whether two points at distance exactly `tol`
# merge must not depend on the CPU, and must match ``((p - q) ** 2).sum() <= tol**2``.
EXACT = {**JIT, "fastmath": False}

_U = np.uint64


@njit(**EXACT)
def _slot(points, head, mask, inv, lo, a, b, c, salt):
    """Slot of grid cell (a, b, c) in the open-addressed table `head`: the slot holding
    it, or the empty slot where it would go (``head[slot] == -1``)."""
    h = (
        (_U(a) * _U(0x9E3779B97F4A7C15))
        ^ (_U(b) * _U(0xC2B2AE3D27D4EB4F))
        ^ (_U(c) * _U(0x165667B19E3779F9))
        ^ _U(salt)
    )
    h = h * _U(0xBF58476D1CE4E5B9)
    s = np.int64((h ^ (h >> _U(29))) & _U(mask))
    while True:
        j = head[s]
        if j < 0:
            return s
        # the cell of a slot is the cell of the representative at its head
        if (
            np.int64(math.floor((points[j, 0] - lo[0]) * inv)) == a
            and np.int64(math.floor((points[j, 1] - lo[1]) * inv)) == b
            and np.int64(math.floor((points[j, 2] - lo[2]) * inv)) == c
        ):
            return s
        s = (s + 1) & mask


@njit(**EXACT)
def weld_kernel(points, tol, cell, lo, head, link, rep, salt):
    """Merge each point into the earliest representative within `tol`, in input order.

    ``points (n, 3)`` float64; ``tol >= 0`` the merge distance; ``cell`` the grid
    spacing, ``>= 3 tol`` (or larger than twice the points' extent); ``lo (3,)``
    float64 the grid origin, at least one cell below every point; ``head (m,)`` int64
    filled with -1, ``m`` a power of two ``> n`` (scratch: hash table of occupied
    cells, each the newest representative in it); ``link (n,)`` int64 scratch (the
    next older representative in the same cell); ``salt`` a random int64 mixed into the
    cell hash, so that no fixed input can make the probes collide (the result does not
    depend on it).

    Writes ``rep (n,)`` int64: point ``i`` becomes a representative (``rep[i] = i``)
    unless an earlier representative lies within ``tol`` (Euclidean); then ``rep[i]``
    is the smallest such index. Representatives are pairwise more than ``tol`` apart
    and every point is within ``tol`` of its representative. Returns their count.

    With ``cell >= 3 tol`` a point within ``tol`` of ``p`` lies, along each axis, in
    ``p``'s cell or in the neighbour on the side of ``p``'s nearer cell face (a margin
    of ``tol / 2`` against rounding), so 8 cells are searched; each holds few
    representatives since they are more than ``tol`` apart.
    """
    n = points.shape[0]
    mask = head.shape[0] - 1
    inv = 1.0 / cell
    tol2 = tol * tol
    count = 0
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        gx, gy, gz = (x - lo[0]) * inv, (y - lo[1]) * inv, (z - lo[2]) * inv
        cx, cy, cz = np.int64(math.floor(gx)), np.int64(math.floor(gy)), np.int64(math.floor(gz))
        ax = cx - 1 if gx - cx < 0.5 else cx
        ay = cy - 1 if gy - cy < 0.5 else cy
        az = cz - 1 if gz - cz < 0.5 else cz
        best = -1
        for a in range(ax, ax + 2):
            for b in range(ay, ay + 2):
                for c in range(az, az + 2):
                    j = head[_slot(points, head, mask, inv, lo, a, b, c, salt)]
                    while j >= 0:
                        if best < 0 or j < best:
                            dx, dy, dz = points[j, 0] - x, points[j, 1] - y, points[j, 2] - z
                            near = abs(dx) <= tol and abs(dy) <= tol and abs(dz) <= tol
                            if near and dx * dx + dy * dy + dz * dz <= tol2:
                                best = j
                        j = link[j]
        if best < 0:
            s = _slot(points, head, mask, inv, lo, cx, cy, cz, salt)
            link[i] = head[s]
            head[s] = i
            rep[i] = i
            count += 1
        else:
            rep[i] = best
    return count
