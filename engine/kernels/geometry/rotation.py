"""Quaternion → rotation matrix, the one formula every kernel uses.

:func:`quaternion_rotation` is compiled without fast-math and is never inlined at
Numba-IR level (which would compile it with the caller's flags): the collision search
(relative poses of body pairs) and the dynamics (world inertia, rotation matrices of a
scene) get the same bits from the same quaternion, whatever code LLVM generates around
the call, and the bits of the plain formula (no contraction into fused multiply-adds).
Its formula is :func:`rotation_entries`, compiled the same way, which returns the entries
as a tuple (for kernels that keep a rotation in registers, not in an array).
"""

from __future__ import annotations

from numba import njit

from engine.kernels.jit import EXACT_BORROW, EXACT_JIT


@njit(**EXACT_JIT)
def quaternion_rotation(q, out):
    """``out (3, 3)`` float64: the rotation of the unit quaternion ``q = (w, x, y, z)``
    (4,) float64 (``world = out @ body``)."""
    m = rotation_entries(q[0], q[1], q[2], q[3])
    for k in range(9):
        out[k // 3, k % 3] = m[k]


@njit(**EXACT_BORROW)
def rotation_entries(w, x, y, z):
    """The 9 entries, row by row, of the rotation of the unit quaternion ``(w, x, y, z)``
    (what :func:`quaternion_rotation` writes; compiled apart, so a caller with fast-math
    gets the same bits)."""
    return (
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    )
