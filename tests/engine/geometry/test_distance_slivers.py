"""Hybrid decides exactly as exact, also for poorly shaped triangles in float32.

The inside test of a face errs by about ulp·size/sin θ (θ the triangle's largest
angle), so the rounding band scales with κ = 1/sin θ; these pairs sit right at
their contact distance, where a too-narrow band would let the certified
iterative answer and the exact kernel disagree.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import triangle_distances


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def _thin_pair(seed: int, aspect: float, gap: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    apex = rng.uniform(0.0, 1.0)  # where the third vertex sits along the long edge
    thin = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [apex, aspect, 0.0]])
    other = rng.normal(size=(3, 3)) * 0.5 + [apex, aspect / 3, 0.0]
    other[:, 2] = np.abs(other[:, 2]) + gap  # above the thin triangle's plane
    rot, shift = _rotation(rng), rng.normal(size=3)
    return thin @ rot.T + shift, other @ rot.T + shift


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    log_aspect=st.floats(-3.0, 0.0),
    log_gap=st.floats(-6.0, -1.0),
    precision=st.sampled_from(["float32", "float64"]),
)
def test_hybrid_decides_as_exact_at_the_contact_distance(seed, log_aspect, log_gap, precision):
    a, b = _thin_pair(seed, 10.0**log_aspect, 10.0**log_gap)
    d = float(triangle_distances(a[None], b[None], "exact", precision).distance[0])
    eps = np.array([d, d * (1 + 1e-7), d * (1 - 1e-7), np.nextafter(d, 0.0)])
    n = len(eps)
    aa, bb = np.repeat(a[None], n, 0), np.repeat(b[None], n, 0)
    exact = triangle_distances(aa, bb, "exact", precision, eps)
    hybrid = triangle_distances(aa, bb, "hybrid", precision, eps)
    exact_contact = exact.distance <= eps.astype(precision)
    hybrid_contact = (hybrid.status == 1) | (
        (hybrid.status == 2) & (hybrid.distance <= eps.astype(precision))
    )
    np.testing.assert_array_equal(hybrid_contact, exact_contact)
