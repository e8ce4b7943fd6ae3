"""The comparison of two paired code paths' results (the fused raw-array kernel and the
block kernel, or a pair resolved directly and as a queued fallback): bit for bit, except
float32 closest points.

In float32 the exact closest points of the same pair can differ in their last bits where
LLVM vectorises the loops differently (measured on an AVX-512 machine: 12 of 6,900
coordinates, at most 5e-6 relative; none on AVX2). Distances, bounds and statuses stay bit
for bit. Points are then held to 2⁻¹⁶ of the pair's scale, on at most 2 % of the pairs.
"""

from __future__ import annotations

import numpy as np

POINT_FIELDS = ("point_a", "point_b")


def assert_same_field(name: str, got: np.ndarray, want: np.ndarray, scale: np.ndarray, msg: str):
    """``got == want`` bit for bit, or for float32 points ``(n, 3)`` within 2⁻¹⁶ ·
    ``scale (n,)`` (the pairs' largest coordinate) on at most 2 % of the rows."""
    if name not in POINT_FIELDS or got.dtype != np.float32:
        np.testing.assert_array_equal(got, want, msg)
        return
    apart = np.abs(got.astype(np.float64) - want.astype(np.float64)).max(axis=1)
    assert (apart <= 2.0**-16 * scale).all(), f"{msg}: {apart.max()} apart"
    assert np.count_nonzero(apart) <= 0.02 * len(apart), f"{msg}: {np.count_nonzero(apart)} rows"
