"""Unit quaternion → rotation matrix on the host (numpy), for the engine's poses and the
clients alike. (Numba kernels keep their own scalar copy in ``engine/kernels/``: they cannot
call numpy code like this.)"""

from __future__ import annotations

import numpy as np

__all__ = ["rotation_matrix"]


def rotation_matrix(quaternion) -> np.ndarray:
    """The rotation matrix of ``quaternion (4,)`` or ``(n, 4)`` (w, x, y, z; taken as
    given, not normalised: pass unit quaternions): ``(3, 3)`` or ``(n, 3, 3)`` float64, with
    ``world = matrix @ body``.

    Raises ``ValueError`` for another shape.
    """
    q = np.asarray(quaternion, dtype=np.float64)
    if q.ndim not in (1, 2) or q.shape[-1] != 4:
        raise ValueError(f"a quaternion is (4,) or (n, 4) (w, x, y, z), got shape {q.shape}")
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)
