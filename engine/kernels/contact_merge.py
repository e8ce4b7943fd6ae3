"""Greedy merging of nearby contact points (the paper's implementation remark)."""

from __future__ import annotations

from numba import njit

from .jit import JIT


@njit(**JIT)
def merge_kernel(points, order, radius, label, centres):
    """Cluster contact points, visiting them in ``order``; returns the cluster count.

    A point joins the nearest existing cluster whose first point lies closer than
    ``radius``, else it starts a cluster. Writes ``label (k,)`` and the clusters'
    first points to ``centres (k, 3)``. Inputs: ``points (k, 3)`` float64,
    ``order (k,)`` int64.
    """
    m = 0
    limit = radius * radius
    for t in range(order.shape[0]):
        k = order[t]
        best = -1
        best_d2 = limit
        for c in range(m):
            dx = centres[c, 0] - points[k, 0]
            dy = centres[c, 1] - points[k, 1]
            dz = centres[c, 2] - points[k, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < best_d2:
                best, best_d2 = c, d2
        if best < 0:
            centres[m, 0], centres[m, 1], centres[m, 2] = points[k, 0], points[k, 1], points[k, 2]
            best = m
            m += 1
        label[k] = best
    return m
