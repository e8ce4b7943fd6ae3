"""Contact history kernels: each contact's tangential spring and allowance carried from the
last step to the contacts of a new configuration (``engine.dynamics.history``).

A contact is the same as one of the last step when it belongs to the same body pair and
its point, in body A's frame, lies within the pair's reach (ε_a + ε_b) of that contact's
point: the nearest such contact gives its history. Merged contacts move as clusters
change, so identity is by place on A's surface, not by index.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.dynamics.contact_forces import (
    DISPLACEMENT,
    HISTORY,
    HISTORY_ALLOWANCE,
    HISTORY_DISPLACEMENT,
    HISTORY_RELEASING,
    NORMAL_SPEED,
)
from engine.kernels.geometry.rotation import quaternion_rotation
from engine.kernels.jit import JIT


@njit(**JIT)
def local_points(bodies, offsets, points, positions, orientations, out):
    """``out (c, 3)``: each contact point in its pair's body A frame, R_aᵀ·(p − x_a)
    (``positions (n, 3)``, ``orientations (n, 4)`` the configuration of the contacts)."""
    rot = np.empty((3, 3))
    for q in range(bodies.shape[0]):
        a = bodies[q, 0]
        quaternion_rotation(orientations[a], rot)
        for c in range(offsets[q], offsets[q + 1]):
            d0 = points[c, 0] - positions[a, 0]
            d1 = points[c, 1] - positions[a, 1]
            d2 = points[c, 2] - positions[a, 2]
            for i in range(3):
                out[c, i] = rot[0, i] * d0 + rot[1, i] * d1 + rot[2, i] * d2


@njit(**JIT)
def matched(bodies, offsets, local, epsilon, count, old_keys, old_offsets, old_local,
            old_values, out):  # fmt: skip
    """``out (c, HISTORY)``: for each new contact (pairs ``bodies (k, 2)``, ``offsets``,
    points ``local (c, 3)`` in A's frame) the values of the nearest contact of the last
    step of the same pair within its reach ``epsilon[a] + epsilon[b]``, else zeros. The
    last step's contacts: pair keys ``old_keys (m,)`` int64 (a·count + b, ascending), their
    ``old_offsets (m + 1,)``, points ``old_local``, values ``old_values (·, HISTORY)``."""
    for q in range(bodies.shape[0]):
        a, b = bodies[q, 0], bodies[q, 1]
        key = a * count + b
        slot = np.searchsorted(old_keys, key)
        found = slot < old_keys.shape[0] and old_keys[slot] == key
        reach = epsilon[a] + epsilon[b]
        for c in range(offsets[q], offsets[q + 1]):
            best, nearest = -1, reach * reach
            if found:
                for o in range(old_offsets[slot], old_offsets[slot + 1]):
                    d0 = local[c, 0] - old_local[o, 0]
                    d1 = local[c, 1] - old_local[o, 1]
                    d2 = local[c, 2] - old_local[o, 2]
                    distance = d0 * d0 + d1 * d1 + d2 * d2
                    if distance <= nearest:
                        best, nearest = o, distance
            for i in range(HISTORY):
                out[c, i] = old_values[best, i] if best >= 0 else 0.0


@njit(**JIT)
def carried(terms, start, overlaps, release, midpoint, out):
    """``out (c, HISTORY)``: the history the contacts of an accepted evaluation leave to
    the next step: the spring's displacement of ``terms`` (for the implicit midpoint rule,
    extrapolated through the midpoint: 2·ξ_mid − ξ_start), the allowance of ``start
    (c, HISTORY)`` less ``release`` (never below 0), and whether the contact is still
    releasing: it had an allowance, or it was releasing and still overlaps (``overlaps
    (c,)``) by more than ``release``."""
    for c in range(terms.shape[0]):
        for i in range(3):
            now = terms[c, DISPLACEMENT + i]
            out[c, HISTORY_DISPLACEMENT + i] = (
                2.0 * now - start[c, HISTORY_DISPLACEMENT + i] if midpoint and now != 0.0 else now
            )
        out[c, HISTORY_ALLOWANCE] = max(start[c, HISTORY_ALLOWANCE] - release, 0.0)
        holding = start[c, HISTORY_ALLOWANCE] > 0.0
        lagging = start[c, HISTORY_RELEASING] != 0.0 and overlaps[c] > release
        out[c, HISTORY_RELEASING] = 1.0 if holding or lagging else 0.0


@njit(**JIT)
def initial_allowance(overlaps, terms, out):
    """Set ``out[c, HISTORY_ALLOWANCE]`` of each contact that is not closing to its overlap
    ``overlaps (c,)``: its spring starts relaxed and lets go of it at the allowance's release
    rate. A closing contact (``terms (c, TERMS)``: NORMAL_SPEED < 0, B's point approaching
    A's: a collision under way) gets none: its spring pushes as it would have."""
    for c in range(overlaps.shape[0]):
        if terms[c, NORMAL_SPEED] < 0.0:
            continue
        out[c, HISTORY_ALLOWANCE] = overlaps[c]
        out[c, HISTORY_RELEASING] = 1.0 if overlaps[c] > 0.0 else 0.0
