"""Triangle–triangle distances and contacts over batches: the host API.

Three kernels (see :mod:`engine.kernels`): ``"exact"`` (the oracle),
``"iterative"`` (block Newton sweeps with a certified duality gap) and
``"hybrid"`` (iterative, then exact for the not-converged pairs), each in
``"float32"`` or ``"float64"``. Three forms:

* :func:`triangle_distances` — paired triangles ``a[t]``, ``b[t]``;
* :func:`triangle_contacts` with ``pairs=None`` — all pairs between two sets,
  streamed (nothing of size ``len(a)·len(b)`` is allocated);
* :func:`triangle_contacts` with ``pairs`` — an explicit list of index pairs.

This module validates, converts, splits work across threads and assembles
results; the kernels only see flat arrays.
"""

from __future__ import annotations

import enum
import os
from dataclasses import dataclass, field

import numpy as np

from engine.arguments import (
    check_epsilon,
    check_iterations,
    check_kernel,
    check_pairs,
    check_precision,
    check_triangles,
    kernel_constants,
)
from engine.errors import InvalidArgumentError
from engine.kernels.geometry import triangle_batch as tb
from engine.workers import worker_pool

__all__ = [
    "DEFAULT_ITERATIONS",
    "DEFAULT_PRECISION",
    "KernelStats",
    "PairStatus",
    "TriangleContacts",
    "TriangleDistances",
    "TriangleSet",
    "triangle_contacts",
    "triangle_distances",
]

DEFAULT_ITERATIONS = 1
"""Sweeps of the iterative kernel. ``benchmarks/kernels.py`` (BENCHMARKS.md): one sweep
certifies 97.5% of near pairs and gives the fastest hybrid kernel; each further sweep
costs more than the few fallbacks it saves (2.5% at 1 sweep, 1.6% at 3, 1.1% at 8)."""
DEFAULT_PRECISION = "float64"
"""Arithmetic of the contact search (``find_contacts``, batches, scenes). BENCHMARKS.md: on
contact queries alone float32 finds exactly the float64 oracle's pairs with hybrid's contact
geometry unchanged, in 3.5–6 % less time (``benchmarks/search_pareto.py``); but in a scene its
rounding moves the contact points of parallel faces from one Picard iteration to the next,
and implicit Picard stops converging on a resting box stack (float64: 3.4 iterations a step;
float32: 286 of 320 steps not converged, ``benchmarks/precision.py``). Poses, velocities and
forces are float64 whatever this is."""
DEFAULT_RTOL = 0.01
"""Converged when the certified gap ``U − L`` is at most ``rtol·ε`` (plus rounding)."""
_SERIAL_PAIRS = 1 << 16  # below this many pairs one thread is faster than a pool


class PairStatus(enum.IntEnum):
    """Per-pair result of a kernel, before any fallback."""

    NO_CONTACT = tb.NO_CONTACT
    CONTACT = tb.CONTACT
    NOT_CONVERGED = tb.NOT_CONVERGED


@dataclass(frozen=True)
class KernelStats:
    """Counters of one call.

    ``pairs`` triangle pairs considered; ``culled`` decided "no contact" by the
    cheap centroid-axis bound; ``iterative`` evaluations of the iterative kernel;
    ``fallbacks`` exact evaluations of not-converged pairs (hybrid).
    """

    pairs: int = 0
    culled: int = 0
    iterative: int = 0
    fallbacks: int = 0

    @classmethod
    def from_array(cls, counts: np.ndarray) -> KernelStats:
        """The counters of a kernel's ``stats (N_STATS,)`` int64 array."""
        slots = (tb.STAT_PAIRS, tb.STAT_CULLED, tb.STAT_ITERATIVE, tb.STAT_FALLBACKS)
        return cls(*(int(counts[k]) for k in slots))


@dataclass(frozen=True)
class TriangleDistances:
    """Result of :func:`triangle_distances` for ``n`` pairs; "float" is the kernel's
    ``precision`` (float32 or float64).

    distance : (n,) float — closest distance (exact for the exact kernel, for
        fallbacks, and within the tolerance for ``CONTACT``; an upper bound for
        iterative ``NO_CONTACT`` / ``NOT_CONVERGED`` pairs)
    lower : (n,) float — certified lower bound on the distance
    point_a, point_b : (n, 3) float — closest points on A and on B
    status : (n,) int8 — :class:`PairStatus` of the first kernel, before fallback
    stats : KernelStats
    """

    distance: np.ndarray
    lower: np.ndarray
    point_a: np.ndarray
    point_b: np.ndarray
    status: np.ndarray
    stats: KernelStats = field(default_factory=KernelStats)


@dataclass(frozen=True)
class TriangleContacts:
    """Pairs within their contact distance; "float" is the kernel's ``precision``
    (float32 or float64).

    All-pairs results are ordered by (index in a, index in b); listed results
    follow the order of the given ``pairs``.

    pairs : (m, 2) int64 — indices into a and b
    distance : (m,) float
    point_a, point_b : (m, 3) float
    status : (m,) int8 — ``CONTACT``, or ``NOT_CONVERGED`` (iterative kernel only:
        pairs that may be in contact)
    stats : KernelStats
    """

    pairs: np.ndarray
    distance: np.ndarray
    point_a: np.ndarray
    point_b: np.ndarray
    status: np.ndarray
    stats: KernelStats = field(default_factory=KernelStats)

    def __len__(self) -> int:
        return len(self.distance)


class TriangleSet:
    """Triangles prepared for the kernels in one precision.

    Each triangle's vertices are rotated (orientation kept) so that vertex 0 sits
    opposite its longest edge, at its largest angle: there the normal and the
    barycentric dual basis are best conditioned, which keeps needles accurate in
    float32. Frames are computed in float64 and then rounded to ``precision``.
    Results refer to triangles by index, so the rotation is invisible to callers.

    Parameters
    ----------
    triangles : (n, 3, 3) float — vertex coordinates per triangle
    precision : "float32" or "float64"
    name : str — how error messages refer to the argument

    Attributes
    ----------
    dtype : numpy.dtype — float32 or float64, of every array below
    coords : (9, n) — rows x0 y0 z0 x1 y1 z1 x2 y2 z2
    frames : (14, n) — per-triangle normal, dual basis, inverse edge lengths, validity,
        conditioning κ = 1/sin θ (θ the angle at vertex 0)
    coords_rm, frames_rm : (n, 9), (n, 14) — row-major copies, for gathering
        arbitrary triangles (one or two cache lines per triangle)
    """

    def __init__(
        self, triangles: np.ndarray, precision: str = "float64", name: str = "triangles"
    ) -> None:
        dtype = check_precision(precision)
        tri = _largest_angle_first(check_triangles(triangles, name, dtype))
        self.dtype = np.dtype(dtype)
        coords = np.ascontiguousarray(tri.reshape(-1, 9).T)
        frames = np.empty((14, len(tri)))
        tb.frames_kernel(coords, frames, 1.0, float(kernel_constants(dtype)[1]))
        self.coords = coords.astype(dtype)
        self.frames = frames.astype(dtype)
        self.coords_rm = np.ascontiguousarray(self.coords.T)
        self.frames_rm = np.ascontiguousarray(self.frames.T)

    def __len__(self) -> int:
        return self.coords.shape[1]

    @classmethod
    def prepared(cls, coords: np.ndarray, frames: np.ndarray) -> TriangleSet:
        """A set from arrays a TriangleSet already prepared (e.g. rigidly moved copies):
        ``coords (9, n)``, ``frames (14, n)`` of one float dtype. Not validated."""
        self = cls.__new__(cls)
        self.dtype = coords.dtype
        self.coords = np.ascontiguousarray(coords)
        self.frames = np.ascontiguousarray(frames)
        self.coords_rm = np.ascontiguousarray(self.coords.T)
        self.frames_rm = np.ascontiguousarray(self.frames.T)
        return self

    def subset(self, index: np.ndarray, precision: str) -> TriangleSet:
        """Triangles ``index (k,)`` (int) in ``precision`` (rounded from this set's arrays)."""
        dtype = check_precision(precision)
        return TriangleSet.prepared(
            self.coords[:, index].astype(dtype), self.frames[:, index].astype(dtype)
        )

    @classmethod
    def of(
        cls, triangles: np.ndarray | TriangleSet, precision: str, name: str = "triangles"
    ) -> TriangleSet:
        """``triangles`` itself if already prepared in ``precision``, else a new set."""
        if isinstance(triangles, TriangleSet):
            if triangles.dtype != np.dtype(check_precision(precision)):
                raise InvalidArgumentError(
                    f"{name} is a {triangles.dtype.name} TriangleSet but precision={precision!r}"
                )
            return triangles
        return cls(triangles, precision, name)


def _largest_angle_first(tri: np.ndarray) -> np.ndarray:
    """Rotate each triangle's vertices so that vertex 0 is opposite its longest edge."""
    opposite = np.stack(
        [
            np.einsum("ij,ij->i", tri[:, 2] - tri[:, 1], tri[:, 2] - tri[:, 1]),
            np.einsum("ij,ij->i", tri[:, 0] - tri[:, 2], tri[:, 0] - tri[:, 2]),
            np.einsum("ij,ij->i", tri[:, 1] - tri[:, 0], tri[:, 1] - tri[:, 0]),
        ],
        axis=1,
    )
    first = np.argmax(opposite, axis=1)
    order = (first[:, None] + np.arange(3)[None, :]) % 3
    return np.take_along_axis(tri, order[:, :, None], axis=1)


def triangle_distances(
    a: np.ndarray,
    b: np.ndarray,
    kernel: str = "hybrid",
    precision: str = "float64",
    epsilon: float | np.ndarray = 0.0,
    *,
    iterations: int = DEFAULT_ITERATIONS,
    rtol: float = DEFAULT_RTOL,
    threads: int | None = None,
) -> TriangleDistances:
    """Distances between paired triangles ``a[t]`` and ``b[t]``.

    Parameters
    ----------
    a, b : (n, 3, 3) float — paired triangles (or :class:`TriangleSet`)
    kernel : "exact", "iterative" or "hybrid"
    precision : "float32" or "float64" — arithmetic of the kernel
    epsilon : float or (n,) float — contact distance: a pair is in contact when
        its distance is at most ``epsilon`` (for bodies with halos ε_a, ε_b pass
        ε_a + ε_b)
    iterations : int — sweeps of the iterative kernel (fixed, no early exit)
    rtol : float — convergence: certified gap at most ``rtol · epsilon``
    threads : int, optional — worker threads (default: all cores)

    Returns
    -------
    TriangleDistances
    """
    sa, sb, dtype, params = _prepare(a, b, kernel, precision, iterations, rtol)
    n = len(sa)
    if len(sb) != n:
        raise InvalidArgumentError(f"a and b must pair up: {n} and {len(sb)} triangles")
    eps = check_epsilon(epsilon, n, dtype, "epsilon")
    distance = np.empty(n, dtype)
    lower = np.empty(n, dtype)
    point_a = np.empty((3, n), dtype)
    point_b = np.empty((3, n), dtype)
    status = np.empty(n, np.int8)

    def run(start: int, stop: int) -> np.ndarray:
        stats = np.zeros(tb.N_STATS, np.int64)
        tb.paired_kernel(
            sa.coords,
            sa.frames,
            sb.coords,
            sb.frames,
            eps,
            start,
            stop,
            params,
            distance,
            lower,
            point_a,
            point_b,
            status,
            stats,
        )
        return stats

    stats = sum(_map_chunks(run, n, n, threads), np.zeros(tb.N_STATS, np.int64))
    return TriangleDistances(
        distance, lower, point_a.T.copy(), point_b.T.copy(), status, KernelStats.from_array(stats)
    )


def triangle_contacts(
    a: np.ndarray | TriangleSet,
    b: np.ndarray | TriangleSet,
    epsilon_a: float | np.ndarray = 0.0,
    epsilon_b: float | np.ndarray = 0.0,
    pairs: np.ndarray | None = None,
    kernel: str = "hybrid",
    precision: str = "float64",
    *,
    iterations: int = DEFAULT_ITERATIONS,
    rtol: float = DEFAULT_RTOL,
    threads: int | None = None,
) -> TriangleContacts:
    """Triangle pairs within contact distance: all pairs, or listed pairs.

    Parameters
    ----------
    a : (na, 3, 3) float or TriangleSet
    b : (nb, 3, 3) float or TriangleSet
    epsilon_a : float or (na,) float — halo of each triangle of a
    epsilon_b : float or (nb,) float — halo of each triangle of b; pair (i, j) is
        in contact when its distance is at most ``epsilon_a[i] + epsilon_b[j]``
    pairs : (k, 2) int, optional — index pairs to test; all ``na·nb`` pairs
        (streamed) when None
    kernel, precision, iterations, rtol, threads : as :func:`triangle_distances`

    Returns
    -------
    TriangleContacts
    """
    sa, sb, dtype, params = _prepare(a, b, kernel, precision, iterations, rtol)
    eps_a = check_epsilon(epsilon_a, len(sa), dtype, "epsilon_a")
    eps_b = check_epsilon(epsilon_b, len(sb), dtype, "epsilon_b")
    rm = (sa.coords_rm, sa.frames_rm, sb.coords_rm, sb.frames_rm)

    if pairs is None:
        n_outer, work = len(sa), len(sa) * len(sb)

        def call(start, stop, out, stats):
            return tb.all_pairs_kernel(
                sa.coords,
                sa.frames,
                sb.coords,
                sb.frames,
                rm,
                eps_a,
                eps_b,
                start,
                stop,
                params,
                out,
                stats,
            )
    else:
        pair_array = check_pairs(pairs, len(sa), len(sb))
        n_outer = work = len(pair_array)

        def call(start, stop, out, stats):
            buffers = tb.listed_workspace(sa.coords_rm)
            return tb.listed_kernel(
                rm, eps_a, eps_b, pair_array, start, stop, params, buffers, out, tb.ZERO, stats
            )

    def run(start: int, stop: int):
        capacity = 1024 + 8 * (stop - start)
        while True:  # count, allocate, fill: a re-run only when the first guess was short
            out = _contact_buffers(capacity, sa.coords)
            stats = np.zeros(tb.N_STATS, np.int64)
            count = call(start, stop, out, stats)
            if count <= capacity:
                return out, count, stats
            capacity = count

    parts = _map_chunks(run, n_outer, work, threads)
    stats = sum((s for _, _, s in parts), np.zeros(tb.N_STATS, np.int64))
    cat = [np.concatenate([o[k][..., :c] for o, c, _ in parts], axis=-1) for k in range(6)]
    return TriangleContacts(
        pairs=np.stack([cat[0], cat[1]], axis=1),
        distance=cat[2],
        point_a=cat[3].T.copy(),
        point_b=cat[4].T.copy(),
        status=cat[5],
        stats=KernelStats.from_array(stats),
    )


# ----------------------------------------------------------------------------- helpers


def _map_chunks(fn, n_outer: int, work: int, threads: int | None) -> list:
    """Run ``fn(start, stop)`` over chunks of ``range(n_outer)``; results in order."""
    if threads is None:
        threads = os.cpu_count() or 1
    if isinstance(threads, bool) or not isinstance(threads, int | np.integer) or threads < 1:
        raise InvalidArgumentError(f"threads must be a positive integer, got {threads!r}")
    if threads == 1 or work < _SERIAL_PAIRS or n_outer < 2:
        return [fn(0, n_outer)]
    bounds = np.linspace(0, n_outer, min(n_outer, 4 * threads) + 1).astype(int)
    pool = worker_pool(int(threads))
    spans = [(int(s), int(e)) for s, e in zip(bounds[:-1], bounds[1:], strict=True) if e > s]
    return [f.result() for f in [pool.submit(fn, s, e) for s, e in spans]]


def _contact_buffers(capacity: int, like: np.ndarray) -> tuple:
    """Output buffers of the contact forms for ``capacity`` results, floats like ``like``."""
    return tb.result_buffers(capacity, like)


def _prepare(a, b, kernel, precision, iterations, rtol) -> tuple:
    """Validated ``(TriangleSet a, TriangleSet b, dtype, kernel params)``.

    ``params = (mode, iterations, rtol, 1, band factor)`` in the kernels' types.
    """
    mode = check_kernel(kernel)
    dtype = check_precision(precision)
    sa, sb = TriangleSet.of(a, precision, "a"), TriangleSet.of(b, precision, "b")
    iterations, rtol = check_iterations(iterations, rtol)
    one, band = kernel_constants(dtype)
    return sa, sb, dtype, (mode, np.int64(iterations), dtype(rtol), one, band)
