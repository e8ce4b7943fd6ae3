"""Quaternion → rotation matrix, the one formula every kernel uses.

:func:`quaternion_rotation` is compiled without fast-math and is never inlined at
Numba-IR level (which would compile it with the caller's flags): the collision search
(relative poses of body pairs) and the dynamics (world inertia, rotation matrices of a
scene) get the same bits from the same quaternion, whatever code LLVM generates around
the call, and the bits of the plain formula (no contraction into fused multiply-adds).
"""

from __future__ import annotations

from numba import njit

from engine.kernels.jit import EXACT_JIT


@njit(**EXACT_JIT)
def quaternion_rotation(q, out):
    """``out (3, 3)`` float64: the rotation of the unit quaternion ``q = (w, x, y, z)``
    (4,) float64 (``world = out @ body``)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0, 0] = 1 - 2 * (y * y + z * z)
    out[0, 1] = 2 * (x * y - w * z)
    out[0, 2] = 2 * (x * z + w * y)
    out[1, 0] = 2 * (x * y + w * z)
    out[1, 1] = 1 - 2 * (x * x + z * z)
    out[1, 2] = 2 * (y * z - w * x)
    out[2, 0] = 2 * (x * z - w * y)
    out[2, 1] = 2 * (y * z + w * x)
    out[2, 2] = 1 - 2 * (x * x + y * y)
