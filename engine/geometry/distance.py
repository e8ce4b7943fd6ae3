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
import os
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from engine.arguments import (
    check_epsilon,
    check_iterations,
    check_kernel,
    check_pairs,
    check_precision,
    check_triangles,
    coordinate_limit,
    kernel_constants,
)
from engine.errors import InvalidArgumentError
from engine.kernels.geometry import paired_fused as pf
from engine.kernels.geometry import triangle_batch as tb
from engine.kernels.geometry import triangle_paired as tp
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
    threads : int, optional — worker threads of the preparation (default: all cores)

    Attributes
    ----------
    dtype : numpy.dtype — float32 or float64, of every array below
    coords : (9, n) — rows x0 y0 z0 x1 y1 z1 x2 y2 z2
    frames : (14, n) — per-triangle normal, dual basis, inverse edge lengths, validity,
        conditioning κ = 1/sin θ (θ the angle at vertex 0)
    coords_rm, frames_rm : (n, 9), (n, 14) — row-major copies, for gathering
        arbitrary triangles (one or two cache lines per triangle; made on first use)
    """

    def __init__(
        self,
        triangles: np.ndarray,
        precision: str = "float64",
        name: str = "triangles",
        *,
        threads: int | None = None,
    ) -> None:
        dtype = check_precision(precision)
        raw = _raw_triangles(triangles, name, dtype)
        n = len(raw)
        self.dtype = np.dtype(dtype)
        self.coords, self.frames = np.empty((9, n), dtype), np.empty((14, n), dtype)
        limit, tiny = _limit_and_tiny(dtype)

        def run(start: int, stop: int) -> int:
            return tp.prepare_kernel(raw, start, stop, limit, tiny, self.coords, self.frames)

        if sum(_map_chunks(run, n, n, threads)):
            _raise_invalid(((triangles, name),), dtype)
        self._threads = threads

    @cached_property
    def coords_rm(self) -> np.ndarray:
        """(n, 9) — row-major copy of :attr:`coords` (made on first use)."""
        return _row_major(self.coords, getattr(self, "_threads", None))

    @cached_property
    def frames_rm(self) -> np.ndarray:
        """(n, 14) — row-major copy of :attr:`frames` (made on first use)."""
        return _row_major(self.frames, getattr(self, "_threads", None))

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
        return self

    def subset(self, index: np.ndarray, precision: str) -> TriangleSet:
        """Triangles ``index (k,)`` (int) in ``precision`` (rounded from this set's arrays)."""
        dtype = check_precision(precision)
        return TriangleSet.prepared(
            self.coords[:, index].astype(dtype), self.frames[:, index].astype(dtype)
        )

    @classmethod
    def of(
        cls,
        triangles: np.ndarray | TriangleSet,
        precision: str,
        name: str = "triangles",
        *,
        threads: int | None = None,
    ) -> TriangleSet:
        """``triangles`` itself if already prepared in ``precision``, else a new set."""
        if isinstance(triangles, TriangleSet):
            _check_set_precision(triangles, precision, name)
            return triangles
        return cls(triangles, precision, name, threads=threads)


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
    limit = _limit_and_tiny(dtype)[0]
    if side_a[0] == side_b[0] == 0 and (params[0] == tb.EXACT or params[1] == 1):
        # both raw: preparation fused into the pair loop (one sweep only, see paired_fused)
        raw_a, raw_b = _common_dtype(side_a[1], side_b[1])
        out = (distance, lower, point_a.reshape(-1), point_b.reshape(-1), status)
        native = params[0] != tb.EXACT and np.dtype(dtype) == np.float32
        kernel_fn = pf.paired_native_kernel if native else pf.paired_raw_kernel
        args = (raw_a.reshape(-1), raw_b.reshape(-1))
    else:
        out = (distance, lower, point_a, point_b, status)
        kernel_fn = tp.paired_kernel
        args = (side_a, side_b)

    def run(start: int, stop: int) -> tuple:
        stats = np.zeros(tb.N_STATS, np.int64)
        bad = kernel_fn(*args, eps, start, stop, params, limit, *out, stats)
        return bad, stats

    parts = _map_chunks(run, n, n, threads)
    if sum(bad for bad, _ in parts):
        _raise_invalid(((a, "a"), (b, "b")), dtype)
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


def _limit_and_tiny(dtype) -> tuple[float, float]:
    """``(largest admissible coordinate, sliver threshold)`` as float64, for ``dtype``."""
    return coordinate_limit(dtype), float(kernel_constants(dtype)[1])


def _check_set_precision(s: TriangleSet, precision: str, name: str) -> None:
    if s.dtype != np.dtype(check_precision(precision)):
        raise InvalidArgumentError(
            f"{name} is a {s.dtype.name} TriangleSet but precision={precision!r}"
        )


def _raw_triangles(x, name: str, dtype) -> np.ndarray:
    """``x`` as a C-contiguous, writable (n, 3, 3) float32 or float64 array for the
    preparation kernels, without a copy where it already is one (float32 only for a float32
    ``dtype``). Anything else goes through :func:`check_triangles` (a validated float64
    copy); the kernels validate the coordinates of the rest."""
    if (
        isinstance(x, np.ndarray)
        and x.ndim == 3
        and x.shape[1:] == (3, 3)
        and (x.dtype == np.float64 or x.dtype == dtype == np.float32)
    ):
        if x.flags.c_contiguous and x.flags.writeable:
            return x
        return np.array(x, order="C")
    return check_triangles(x, name, dtype)


def _common_dtype(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raw triangle arrays ``x, y (n, 3, 3)`` in one dtype (float32 widened to float64, which
    is exact), so that the fused kernel has one specialisation per dtype."""
    if x.dtype == y.dtype:
        return x, y
    return x.astype(np.float64), y.astype(np.float64)


def _row_major(columns: np.ndarray, threads: int | None) -> np.ndarray:
    """``columns (k, n)`` as a new C-contiguous ``(n, k)`` array."""
    out = np.empty(columns.shape[::-1], columns.dtype)
    n = columns.shape[1]
    _map_chunks(lambda s, e: tp.transpose_kernel(columns, s, e, out), n, 4 * n, threads)
    return out


def _raise_invalid(arguments, dtype) -> None:
    """Raise :func:`check_triangles`' error for the first invalid raw argument of
    ``arguments ((value, name), ...)`` (a kernel counted invalid triangles)."""
    for value, name in arguments:
        if not isinstance(value, TriangleSet):
            check_triangles(value, name, dtype)
    raise InvalidArgumentError("triangles hold non-finite or too large coordinates")


def _paired_sides(a, b, precision: str, dtype) -> tuple:
    """``((n, side), (n, side))`` of :func:`triangle_distances`' two arguments: side
    ``(0, raw, empty, empty)`` for raw triangles (prepared in the kernel), ``(1, empty raw,
    coords, frames)`` for a :class:`TriangleSet`. Empty raw arrays take the other side's
    raw dtype, so that mixed calls reuse a compiled specialisation."""
    raws = [
        None if isinstance(x, TriangleSet) else _raw_triangles(x, name, dtype)
        for x, name in ((a, "a"), (b, "b"))
    ]
    raw_dtype = next((r.dtype for r in raws if r is not None), np.dtype(dtype))
    sides = []
    for x, raw, name in zip((a, b), raws, ("a", "b"), strict=True):
        if raw is None:
            _check_set_precision(x, precision, name)
            empty = np.empty((0, 3, 3), raw_dtype)
            sides.append((len(x), (np.int64(1), empty, x.coords, x.frames)))
        else:
            empty9, empty14 = np.empty((9, 0), dtype), np.empty((14, 0), dtype)
            sides.append((len(raw), (np.int64(0), raw, empty9, empty14)))
    return sides[0], sides[1]
