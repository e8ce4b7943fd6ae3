"""Broad phase of a many-body scene: candidate body pairs from bounding spheres.

:func:`candidate_pairs` lists every pair of bodies whose bounding spheres overlap
(``|c_i − c_j| ≤ r_i + r_j``), except pairs of two fixed bodies, for the narrow phase.

Method: a hierarchical uniform grid (:mod:`engine.kernels.collision.broadphase`). Bodies are
grouped into levels by the size of their bounding box (a factor 4 per level); a level's
cells are 1.5 times its widest box. A body enters the cells its box overlaps at its own
level and at every coarser level — at most 8 per level, so a huge fixed plane or
container costs a cell or two, not millions, and small bodies are tested against it in
that coarse cell. A pair is tested only at the level of its larger body and only in the
one cell that owns it (both boxes' lowest cells decide), so it is found once. Cell lists
are a spatial hash (64-bit cell hashes, counting-sorted into buckets); the pairs are
then put in order by a counting sort on the first index. Fixed–fixed pairs are skipped
before their test.

Cost, for ``n`` bodies in ``L`` occupied levels: at most ``8 n L`` entries, linear-time
bucketing, and per cell the tests of its native bodies against all its entries — about
``n`` times the number of neighbours for bodies of similar size at bounded density, plus
one test per small body for each large body whose cell holds it. Memory is one row per
such test (an upper bound on the pairs). Measured (benchmarks/broadphase.py, one core):
24,576 equal spheres in a packed grid, about 7 ms (300 ns per body, 90 times faster than
brute force); 1,000 bodies of radii 1…8 on a plane-like fixed body, 0.3 ms.
"""

from __future__ import annotations

import numpy as np

from engine.arguments import coordinate_limit
from engine.errors import InvalidArgumentError
from engine.kernels.collision import broadphase as kb

__all__ = ["CandidateList", "candidate_pairs", "overlapping_pairs"]

SLACK = 64 * float(np.finfo(np.float64).eps)
"""Relative widening of each bounding box, so that rounding in the cell indices never
separates two spheres that pass the overlap test."""
MIN_CELL = 2.0**-40
"""Smallest cell size relative to the scene's extent (keeps cell indices within int64)."""
LEVEL_BITS = 2
"""Levels group diameters within a factor ``2**LEVEL_BITS``."""
CELL_FACTOR = 1.5
"""Cell size of a level over its largest diameter."""
BUCKET_LOAD = 2
"""Entries per hash bucket (rounded to a power of two of buckets)."""
SMALL_SCENE = 64
"""Up to this many bodies every pair is tested
(:func:`~engine.kernels.collision.broadphase.all_pairs`): the grid's set-up (levels,
hashing, sorting) costs tens of µs. ``benchmarks/broadphase.py``, the whole call with its
checks: 11–42 µs by brute force against 48–59 µs through the grid for 2–64 bodies; the
grid wins from about 100 (76 against 153 µs at 128)."""
LIST_SKIN = 0.05
"""Growth of a free body's bounding radius in a :class:`CandidateList`, relative to it."""
_ROUNDING = 2.0**-20
"""Relative share of the growth a body may not use (rounding of the two overlap tests)."""
_NO_PAIRS = np.zeros((0, 2), np.int64)


def candidate_pairs(centres, radii, fixed=None) -> np.ndarray:
    """Pairs of bodies whose bounding spheres overlap, fixed–fixed pairs excluded.

    Parameters
    ----------
    centres : (n, 3) array_like of float
        Centres of the bounding spheres (e.g. of the root surrogates, in world frame).
    radii : (n,) array_like of float
        Their radii, finite and non-negative.
    fixed : (n,) array_like of bool, optional
        True for fixed bodies; pairs of two fixed bodies are never tested. Default: none.

    Returns
    -------
    (k, 2) ndarray of int64
        Pairs ``(i, j)``, ``i < j``, sorted lexicographically, each once, such that
        ``dx² + dy² + dz² ≤ (r_i + r_j)²`` in float64 (touching spheres included) and
        not both fixed.

    Raises
    ------
    InvalidArgumentError
        Wrong shapes or dtypes, non-finite or too large values, negative radii.
    """
    return overlapping_pairs(*_check(centres, radii, fixed))


def overlapping_pairs(c: np.ndarray, r: np.ndarray, f: np.ndarray) -> np.ndarray:
    """:func:`candidate_pairs` of checked arrays, for callers that own them (a scene):
    ``c (n, 3)``, ``r (n,)`` C-contiguous float64, finite, ``r ≥ 0``; ``f (n,)`` bool."""
    n = len(r)
    if n < 2 or f.all():
        return _NO_PAIRS.copy()
    if n <= SMALL_SCENE:
        out = np.empty((n * (n - 1) // 2, 2), np.int64)
        return out[: kb.all_pairs(c, r, f, out)].copy()
    level, sizes, origin, reach = _grid(c, r)

    counts = np.empty(n, np.int64)
    kb.count_entries(c, reach, level, sizes, origin, counts)
    offsets = np.zeros(n + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    total = int(offsets[-1])
    buckets = 1 << max(total // BUCKET_LOAD, 1).bit_length()
    slots, bodies, tags = (np.empty(total, np.int64) for _ in range(3))
    kb.fill_entries(c, reach, level, sizes, origin, offsets, buckets, slots, bodies, tags)

    starts = np.empty(2 * buckets + 1, np.int64)
    sorted_bodies, sorted_tags = np.empty(total, np.int64), np.empty(total, np.int64)
    kb.bucket_sort(slots, bodies, tags, starts, sorted_bodies, sorted_tags)
    bounds = np.empty(buckets, np.int64)
    kb.pair_bounds(starts, bounds)
    offsets = np.zeros(buckets + 1, np.int64)
    np.cumsum(bounds, out=offsets[1:])
    pairs, found = np.empty((int(offsets[-1]), 2), np.int64), np.empty(buckets, np.int64)
    kb.bucket_pairs(starts, sorted_bodies, sorted_tags, c, r, f, offsets, pairs, found)
    out = np.empty((int(found.sum()), 2), np.int64)
    return out[: kb.sort_pairs(pairs, offsets, found, n, out)]


class CandidateList:
    """The broad phase of a scene kept between configurations (a Verlet list).

    The list holds the pairs whose spheres overlap with each free body's radius grown by
    ``skin``·r (fixed bodies: not grown), and the centres it was made at. While every
    free body's centre stays within its growth of where it was listed (less a rounding
    share of 2⁻²⁰ and 2⁻⁴⁰ of the scene's coordinates) and no fixed body has moved, a pair
    not listed cannot overlap, so :meth:`pairs` filters the list by the exact test
    instead of running the grid again; otherwise, or when the radii or the fixed mask
    changed, the list is made again. Either way the answer is :func:`overlapping_pairs`'s
    row for row: a function of the arguments alone, whatever was asked before.

    skin : float — growth relative to each free body's radius (0: a new list every call)
    """

    def __init__(self, skin: float = LIST_SKIN) -> None:
        skin = float(skin)
        if not (np.isfinite(skin) and skin >= 0):
            raise InvalidArgumentError(f"skin must be finite and >= 0, got {skin}")
        self.skin = skin
        self.made = 0  # lists made (each a full broad phase)
        self.reused = 0  # calls answered by filtering the list
        self._listed: tuple | None = None  # (centres, radii, fixed, allowed, pairs)

    def pairs(self, c: np.ndarray, r: np.ndarray, f: np.ndarray) -> np.ndarray:
        """:func:`overlapping_pairs` ``(k, 2)`` int64 of checked arrays ``c (n, 3)``,
        ``r (n,)`` float64, ``f (n,)`` bool (as that function takes them)."""
        if len(r) <= SMALL_SCENE or self.skin == 0:
            return overlapping_pairs(c, r, f)
        listed = self._listed
        if (
            listed is not None
            and listed[0].shape == c.shape
            and np.array_equal(listed[1], r)
            and np.array_equal(listed[2], f)
            and kb.within_reach(c, listed[0], listed[3])
        ):
            self.reused += 1
            out = np.empty_like(listed[4])
            return out[: kb.filter_pairs(listed[4], c, r, out)].copy()
        grow = np.where(f, 0.0, self.skin * r)
        scale = float(np.abs(c).max()) + float(r.max())
        allowed = np.maximum(grow * (1.0 - _ROUNDING) - 2.0**-40 * scale, 0.0)
        candidates = overlapping_pairs(c, r + grow, f)
        self._listed = (c.copy(), r.copy(), f.copy(), allowed, candidates)
        self.made += 1
        out = np.empty_like(candidates)
        return out[: kb.filter_pairs(candidates, c, r, out)].copy()


def _grid(c: np.ndarray, r: np.ndarray) -> tuple:
    """``(level (n,) int64, sizes (L,) float64, origin (3,), reach (n,))``.

    Boxes are widened by ``SLACK`` of the largest magnitude in their cell-index arithmetic;
    levels group box widths by ``LEVEL_BITS`` binades (widths below ``MIN_CELL`` of the
    scene's extent join the finest); a level's cell is ``CELL_FACTOR`` times its widest
    box, and at least that floor.
    """
    low, high, scale = np.empty(3), np.empty(3), np.empty(len(r))
    kb.scene_box(c, r, low, high, scale)
    extent = float((high - low).max())
    floor = MIN_CELL * extent if extent > 0 else 1.0
    reach = r + SLACK * (r + scale + np.abs(low).max())
    width = 2.0 * reach
    exponent = np.frexp(np.maximum(width, floor))[1]
    binades, level = np.unique(exponent // LEVEL_BITS, return_inverse=True)
    sizes = np.zeros(len(binades))
    np.maximum.at(sizes, level, width)
    sizes = np.maximum(CELL_FACTOR * sizes, floor)
    return level.astype(np.int64), sizes, low, reach


def _check(centres, radii, fixed) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(c (n, 3) float64, r (n,) float64, f (n,) bool)``, C-contiguous, from the arguments
    of :func:`candidate_pairs`; raises :class:`InvalidArgumentError` as it documents."""
    c = _real(centres, "centres", "(n, 3)")
    if c.ndim != 2 or c.shape[1] != 3:
        raise InvalidArgumentError(f"centres must have shape (n, 3), got {c.shape}")
    n = len(c)
    r = _real(radii, "radii", f"({n},)")
    if r.shape != (n,):
        raise InvalidArgumentError(f"radii must have shape ({n},), got {r.shape}")
    limit = coordinate_limit(np.float64)
    for arr, name in ((c, "centres"), (r, "radii")):
        finite = np.isfinite(arr) & (np.abs(arr) <= limit)
        if not finite.all():
            bad = int(np.flatnonzero(finite.reshape(n, -1).all(axis=1) == 0)[0])
            raise InvalidArgumentError(
                f"{name} must be finite and within ±{limit:.3g}; body {bad} is not"
            )
    if (r < 0).any():
        bad = int(np.flatnonzero(r < 0)[0])
        raise InvalidArgumentError(f"radii must be non-negative; body {bad} has {r[bad]}")
    if fixed is None:
        return c, r, np.zeros(n, np.bool_)
    f = np.asarray(fixed)
    if f.dtype != np.bool_ or f.shape != (n,):
        raise InvalidArgumentError(
            f"fixed must be a boolean mask of shape ({n},), got {f.dtype} {f.shape}"
        )
    return c, r, np.ascontiguousarray(f)


def _real(x, name: str, shape: str) -> np.ndarray:
    """``x`` as a C-contiguous float64 array (``shape`` names the expected shape in errors)."""
    if np.iscomplexobj(x):
        raise InvalidArgumentError(f"{name} must be real, got complex values")
    try:
        return np.ascontiguousarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidArgumentError(f"{name} must be a numeric {shape} array: {exc}") from None
