"""Triangles prepared for the kernels (:class:`TriangleSet`) and the host helpers shared by the
triangle-distance API (:mod:`engine.geometry.distance`): raw-array checks, chunked work over
worker threads, the row-major copies."""

from __future__ import annotations

import os
from functools import cached_property

import numpy as np

from engine.arguments import check_precision, check_triangles, coordinate_limit, kernel_constants
from engine.errors import InvalidArgumentError
from engine.kernels.geometry import triangle_paired as tp
from engine.workers import worker_pool

__all__ = ["TriangleSet"]

_SERIAL_PAIRS = 1 << 16  # below this many pairs one thread is faster than a pool


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
        raw = raw_triangles(triangles, name, dtype)
        n = len(raw)
        self.dtype = np.dtype(dtype)
        self.coords, self.frames = np.empty((9, n), dtype), np.empty((14, n), dtype)
        limit, tiny = limit_and_tiny(dtype)

        def run(start: int, stop: int) -> int:
            return tp.prepare_kernel(raw, start, stop, limit, tiny, self.coords, self.frames)

        if sum(map_chunks(run, n, n, threads)):
            raise_invalid(((triangles, name),), dtype)
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
            check_set_precision(triangles, precision, name)
            return triangles
        return cls(triangles, precision, name, threads=threads)


def map_chunks(fn, n_outer: int, work: int, threads: int | None) -> list:
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


def limit_and_tiny(dtype) -> tuple[float, float]:
    """``(largest admissible coordinate, sliver threshold)`` as float64, for ``dtype``."""
    return coordinate_limit(dtype), float(kernel_constants(dtype)[1])


def check_set_precision(s: TriangleSet, precision: str, name: str) -> None:
    if s.dtype != np.dtype(check_precision(precision)):
        raise InvalidArgumentError(
            f"{name} is a {s.dtype.name} TriangleSet but precision={precision!r}"
        )


def raw_triangles(x, name: str, dtype) -> np.ndarray:
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


def _row_major(columns: np.ndarray, threads: int | None) -> np.ndarray:
    """``columns (k, n)`` as a new C-contiguous ``(n, k)`` array."""
    out = np.empty(columns.shape[::-1], columns.dtype)
    n = columns.shape[1]
    map_chunks(lambda s, e: tp.transpose_kernel(columns, s, e, out), n, 4 * n, threads)
    return out


def raise_invalid(arguments, dtype) -> None:
    """Raise :func:`check_triangles`' error for the first invalid raw argument of
    ``arguments ((value, name), ...)`` (a kernel counted invalid triangles)."""
    for value, name in arguments:
        if not isinstance(value, TriangleSet):
            check_triangles(value, name, dtype)
    raise InvalidArgumentError("triangles hold non-finite or too large coordinates")
