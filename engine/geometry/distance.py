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
results; the kernels only see flat arrays. Raw triangle arrays are prepared (and their
coordinates validated) by one kernel pass; the paired form prepares them inside its kernel,
so nothing of size ``n`` but the results is allocated: with two raw arrays (writable C-contiguous
float32 or float64 ones are used in place, no copy) and the exact kernel or one sweep, each
pair is prepared inside the pair loop (``kernels/geometry/paired_fused.py``); otherwise
block by block into buffers (``kernels/geometry/triangle_paired.py``). Both give the same
bits, with one deliberate exception: the float32 one-sweep kernels (``"iterative"``,
``"hybrid"``) on two raw arrays prepare each triangle in float32 (coordinates rounded to
float32, then float32 arithmetic; 1.7× faster than float64) and rebuild face points from
their barycentrics. Their certified decisions are still the exact kernel's, their bounds
still bracket the distance, and hybrid fallbacks are still the exact kernel's results bit
for bit; but certified values and points may differ from those of prepared
:class:`TriangleSet` arguments (or of other sweep counts) by rounding, and where the
closest points are not unique (parallel faces) the points may be other closest points.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from engine.arguments import (
    check_epsilon,
    check_iterations,
    check_kernel,
    check_pairs,
    check_precision,
    coordinate_limit,
    kernel_constants,
)
from engine.errors import InvalidArgumentError
from engine.geometry.triangle_set import (
    TriangleSet,
    check_set_precision,
    limit_and_tiny,
    map_chunks,
    raise_invalid,
    raw_triangles,
)
from engine.kernels.geometry import paired_fused as pf
from engine.kernels.geometry import triangle_batch as tb
from engine.kernels.geometry import triangle_paired as tp

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
    dtype, params = _parameters(kernel, precision, iterations, rtol)
    (n, side_a), (nb, side_b) = _paired_sides(a, b, precision, dtype)
    if nb != n:
        raise InvalidArgumentError(f"a and b must pair up: {n} and {nb} triangles")
    eps = _epsilon_column(epsilon, n, dtype)
    distance = np.empty(n, dtype)
    lower = np.empty(n, dtype)
    point_a = np.empty((n, 3), dtype)
    point_b = np.empty((n, 3), dtype)
    status = np.empty(n, np.int8)
    limit = limit_and_tiny(dtype)[0]
    if side_a[0] == side_b[0] == 0 and (params[0] == tb.EXACT or params[1] == 1):
        # both raw: preparation fused into the pair loop (one sweep only, see paired_fused)
        raw_a, raw_b = _common_dtype(side_a[1], side_b[1])
        out = (distance, lower, point_a.reshape(-1), point_b.reshape(-1), status)
        native = params[0] != tb.EXACT and np.dtype(dtype) == np.float32
        kernel_fn = pf.paired_raw_kernel
        args, flags = (raw_a.reshape(-1), raw_b.reshape(-1)), (native,)
    else:
        out = (distance, lower, point_a, point_b, status)
        kernel_fn = tp.paired_kernel
        args, flags = (side_a, side_b), ()

    def run(start: int, stop: int) -> tuple:
        stats = np.zeros(tb.N_STATS, np.int64)
        bad = kernel_fn(*args, eps, start, stop, params, limit, *flags, *out, stats)
        return bad, stats

    parts = map_chunks(run, n, n, threads)
    if sum(bad for bad, _ in parts):
        raise_invalid(((a, "a"), (b, "b")), dtype)
    stats = sum((s for _, s in parts), np.zeros(tb.N_STATS, np.int64))
    return TriangleDistances(
        distance, lower, point_a, point_b, status, KernelStats.from_array(stats)
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
    dtype, params = _parameters(kernel, precision, iterations, rtol)
    sa = TriangleSet.of(a, precision, "a", threads=threads)
    sb = TriangleSet.of(b, precision, "b", threads=threads)
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

    parts = map_chunks(run, n_outer, work, threads)
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


def _epsilon_column(epsilon, n: int, dtype) -> np.ndarray:
    """``epsilon`` as an ``(n,)`` array of ``dtype``, validated by :func:`check_epsilon`; a
    valid scalar is filled in directly: no float64 column to check and convert (measured
    1 ns a pair, 200,000 pairs)."""
    if np.ndim(epsilon) == 0 and not np.iscomplexobj(epsilon):
        try:
            value = float(epsilon)
        except (TypeError, ValueError):
            value = float("nan")
        if 0.0 <= value <= coordinate_limit(dtype):
            return np.full(n, value, dtype)
    return check_epsilon(epsilon, n, dtype, "epsilon")


def _contact_buffers(capacity: int, like: np.ndarray) -> tuple:
    """Output buffers of the contact forms for ``capacity`` results, floats like ``like``."""
    return tb.result_buffers(capacity, like)


def _parameters(kernel, precision, iterations, rtol) -> tuple:
    """Validated ``(dtype, kernel params)``.

    ``params = (mode, iterations, rtol, 1, band factor)`` in the kernels' types.
    """
    mode = check_kernel(kernel)
    dtype = check_precision(precision)
    iterations, rtol = check_iterations(iterations, rtol)
    one, band = kernel_constants(dtype)
    return dtype, (mode, np.int64(iterations), dtype(rtol), one, band)


def _common_dtype(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raw triangle arrays ``x, y (n, 3, 3)`` in one dtype (float32 widened to float64, which
    is exact), so that the fused kernel has one specialisation per dtype."""
    if x.dtype == y.dtype:
        return x, y
    return x.astype(np.float64), y.astype(np.float64)


def _paired_sides(a, b, precision: str, dtype) -> tuple:
    """``((n, side), (n, side))`` of :func:`triangle_distances`' two arguments: side
    ``(0, raw, empty, empty)`` for raw triangles (prepared in the kernel), ``(1, empty raw,
    coords, frames)`` for a :class:`TriangleSet`. Empty raw arrays take the other side's
    raw dtype, or float64 (NumPy's default) when both sides are sets, so that sets, mixed
    calls and multi-sweep raw calls reuse one compiled specialisation."""
    raws = [
        None if isinstance(x, TriangleSet) else raw_triangles(x, name, dtype)
        for x, name in ((a, "a"), (b, "b"))
    ]
    raw_dtype = next((r.dtype for r in raws if r is not None), np.dtype(np.float64))
    sides = []
    for x, raw, name in zip((a, b), raws, ("a", "b"), strict=True):
        if raw is None:
            check_set_precision(x, precision, name)
            empty = np.empty((0, 3, 3), raw_dtype)
            sides.append((len(x), (np.int64(1), empty, x.coords, x.frames)))
        else:
            empty9, empty14 = np.empty((9, 0), dtype), np.empty((14, 0), dtype)
            sides.append((len(raw), (np.int64(0), raw, empty9, empty14)))
    return sides[0], sides[1]
