"""Level-synchronous multiresolution traversal of two surrogate trees (one call per query).

The front is a list of node pairs, starting at the two roots. Each level is split
into leaf–leaf pairs, streamed through :func:`~engine.kernels.triangle_batch.listed_kernel`
with the leaf parameters (their contacts are final), and pairs with a surrogate,
streamed with the surrogate parameters (iterative, or exact): a pair reported in
contact or not converged is unfolded — the node with the larger ε is replaced by
its children (a leaf is never unfolded) — into the next level's front.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .jit import JIT
from .triangle_batch import ZERO, listed_kernel


@njit(**JIT)
def traverse_kernel(
    rm, eps_a, eps_b, tree_a, tree_b, coarse_params, leaf_params, out, stats, levels
):
    """Contacts between two trees; returns ``(count, number of levels, unfoldings)``.

    ``rm`` = row-major (coords, frames) of A's nodes and of B's nodes (in A's frame);
    ``eps_a, eps_b (N,)`` per-node ε; ``tree_* = (face, first_child, child_count)``
    int32 arrays (face < 0 for a surrogate). ``out`` receives the leaf–leaf results
    (node indices) as in :func:`listed_kernel`; the count may exceed its capacity
    (the host then re-runs). ``levels`` (int64) receives the pairs evaluated per
    level (levels beyond its length are counted but not stored).
    """
    face_a, first_a, count_a = tree_a
    face_b, first_b, count_b = tree_b
    front = np.zeros((1, 2), np.int64)
    n = ZERO
    depth = ZERO
    unfoldings = ZERO
    while front.shape[0] > 0:
        m = front.shape[0]
        if depth < levels.shape[0]:
            levels[depth] = m
        depth += 1
        finest = np.empty((m, 2), np.int64)
        coarse = np.empty((m, 2), np.int64)
        nf = ZERO
        nc = ZERO
        for t in range(m):
            i, j = front[t, 0], front[t, 1]
            if face_a[i] >= 0 and face_b[j] >= 0:
                finest[nf, 0], finest[nf, 1] = i, j
                nf += 1
            else:
                coarse[nc, 0], coarse[nc, 1] = i, j
                nc += 1
        if nf > 0:
            n = listed_kernel(rm, eps_a, eps_b, finest, ZERO, nf, leaf_params, out, n, stats)
        if nc == 0:
            break
        hits = (
            np.empty(nc, np.int64),
            np.empty(nc, np.int64),
            np.empty(nc, out[2].dtype),
            np.empty((3, nc), out[2].dtype),
            np.empty((3, nc), out[2].dtype),
            np.empty(nc, np.int8),
        )
        h = listed_kernel(rm, eps_a, eps_b, coarse, ZERO, nc, coarse_params, hits, ZERO, stats)
        hi, hj = hits[0], hits[1]
        unfoldings += h
        size = ZERO
        for k in range(h):
            i, j = hi[k], hj[k]
            if face_a[i] < 0 and (face_b[j] >= 0 or eps_a[i] >= eps_b[j]):
                size += count_a[i]
            else:
                size += count_b[j]
        front = np.empty((size, 2), np.int64)
        r = ZERO
        for k in range(h):
            i, j = hi[k], hj[k]
            if face_a[i] < 0 and (face_b[j] >= 0 or eps_a[i] >= eps_b[j]):
                for c in range(first_a[i], first_a[i] + count_a[i]):
                    front[r, 0], front[r, 1] = c, j
                    r += 1
            else:
                for c in range(first_b[j], first_b[j] + count_b[j]):
                    front[r, 0], front[r, 1] = i, c
                    r += 1
    return n, depth, unfoldings
