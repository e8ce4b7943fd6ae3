"""Compile (or load from the cache) every kernel, as the service does before it is ready.

A cold compile is CPU-bound and single-threaded per process (about 5 minutes on one core
of a 2-core EPYC VM). :func:`warmup` therefore splits the work into *parts* that compile
mostly disjoint kernels (part 0 builds trees with every fit and runs the contact searches;
part 1 the triangle-set kernels, :func:`mesh_distance`, the broad phase and a step of each
scheme), ordered so that a kernel both need is mostly compiled by one and loaded by the
other (measured cold on the 2-vCPU VM, the two at once: 131 and 142 s; with the broad phase
and the steps in part 0, 158 and 111 s, and ``warmup(2)`` 171 s where it is now 153 s), and, given
``workers > 1``, compiles all parts but the first in spawned processes while this process
compiles the first. The other processes write their machine code into the shared on-disk
cache (``$NUMBA_CACHE_DIR``), and this process then runs those parts too, loading it.
With a warm cache every part only loads, and ``workers`` changes nothing but the start of
a few processes; with ``workers=1`` everything runs here, in order.
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import multiprocessing
import os
import platform
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numba
import numpy as np

from engine.arguments import KERNELS, PRECISIONS
from engine.collision.batch import find_contacts_batch
from engine.collision.broadphase import SMALL_SCENE, CandidateList, candidate_pairs
from engine.collision.contacts import find_contacts
from engine.collision.proximity import mesh_distance
from engine.dynamics.picard import TunnellingWarning
from engine.errors import InvalidArgumentError
from engine.geometry.distance import TriangleSet, triangle_contacts, triangle_distances
from engine.geometry.pose import Pose
from engine.geometry.shapes import box
from engine.scene import SCHEMES, Scene
from engine.trees.build import build_tree
from engine.trees.surrogates import FITS

__all__ = ["PARTS", "SECTIONS", "default_workers", "warm_scene", "warm_stamp", "warmup"]


_NEAR = ([0.9, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])  # a pose whose box touches the first


def _fits() -> None:
    """Tree builds with every fit ("epsilon" and "paper" run the surrogate_fit kernels)."""
    for fit in FITS:
        build_tree(box(), 0.05, fit=fit)


def _batched(precision: str) -> None:
    """The batched search in ``precision``, every kernel (one compile: the kernel is an
    argument of the batch kernel)."""
    tree = build_tree(box(), 0.05)
    for kernel in KERNELS:
        pair = (tree, Pose.identity(), tree, Pose(*_NEAR))
        find_contacts_batch([pair], kernel=kernel, precision=precision)


def _single(precision: str) -> None:
    """The single search in ``precision``, every kernel, with and without the hierarchy."""
    tree = build_tree(box(), 0.05)
    for kernel in KERNELS:
        for hierarchy in (True, False):
            find_contacts(
                tree,
                Pose.identity(),
                tree,
                Pose(*_NEAR),
                kernel=kernel,
                hierarchy=hierarchy,
                precision=precision,
            )


def _triangles(precision: str) -> None:
    """The triangle-set API in ``precision``: distances from sets and from raw float64
    (and, for float32, float32) arrays, all-pairs and listed contacts."""
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 0, 1], [0, 1, 1]]], float)
    sa = TriangleSet(tri, precision)
    TriangleSet(tri.astype(precision), precision)  # prepared from float32 or float64
    for kernel in KERNELS:
        triangle_distances(sa, sa, kernel, precision, 0.1, threads=1)
        triangle_distances(tri, tri, kernel, precision, 0.1, threads=1)  # raw: fused kernel
        if precision == "float32":  # float32 meshes as they come
            tri32 = tri.astype(np.float32)
            triangle_distances(tri32, tri32, kernel, precision, 0.1, threads=1)
        triangle_contacts(sa, sa, 0.1, 0.1, kernel=kernel, precision=precision, threads=1)
        triangle_contacts(
            sa, sa, 0.1, 0.1, pairs=[[0, 1]], kernel=kernel, precision=precision, threads=1
        )


def _mesh_distances() -> None:
    """:func:`mesh_distance` in both precisions."""
    tree = build_tree(box(), 0.05)
    for precision in PRECISIONS:
        mesh_distance(tree, Pose.identity(), tree, Pose(*_NEAR), precision=precision)


def _broad_phase() -> None:
    """The broad phase's grid path, and a scene's kept candidate list (made, then filtered)."""
    many = np.arange(3 * (SMALL_SCENE + 1), dtype=float).reshape(-1, 3)
    candidate_pairs(many, np.ones(len(many)), np.zeros(len(many), bool))
    kept = CandidateList()
    for _ in range(2):
        kept.pairs(many, np.ones(len(many)), np.zeros(len(many), bool))


def _steps(schemes: tuple[str, ...]) -> None:
    """One step of a small scene (two boxes over a plane, the lower one spinning) per
    scheme of ``schemes``, in turn: the broad phase, forces, motion update."""
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add_plane(size=4.0, divisions=2)
    scene.add_body(box(), position=(0.0, 0.0, 0.505), angular_velocity=(0.0, 0.0, 1.0))
    scene.add_body(box(), position=(0.3, 0.0, 1.52))
    with warnings.catch_warnings():  # a synthetic scene: its fast spin may warn of tunnelling
        warnings.simplefilter("ignore", TunnellingWarning)
        for scheme in schemes:
            scene.step(1e-3, scheme)


#: The warm-up's work as ``(name, function, arguments)`` sections that a process can run
#: alone (``benchmarks/device/warm_wide.py`` runs each in a process of its own on a
#: many-core machine); :data:`PARTS` runs them all, in two parts.
SECTIONS = (
    *((f"batched search {p}", _batched, (p,)) for p in PRECISIONS),
    *((f"steps {s}", _steps, ((s, s),)) for s in SCHEMES),  # the second: warm starts
    *((f"single search {p}", _single, (p,)) for p in PRECISIONS),
    *((f"triangle sets {p}", _triangles, (p,)) for p in PRECISIONS),
    ("fits", _fits, ()),
    ("mesh_distance", _mesh_distances, ()),
    ("broad phase", _broad_phase, ()),
)


def _tree_part() -> None:
    """Tree builds (every fit), single and batched searches in both precisions (float64
    first: :func:`_triangle_part` steps scenes with them)."""
    _fits()
    for precision in reversed(PRECISIONS):  # first: _triangle_part compiles the flat search
        _batched(precision)
    for precision in PRECISIONS:
        _single(precision)


def _triangle_part() -> None:
    """The triangle-set API and :func:`mesh_distance`, in both precisions; then the broad
    phase and one step of every scheme (their searches loaded, by then, from what
    :func:`_tree_part` compiled)."""
    for precision in PRECISIONS:
        _triangles(precision)
    _mesh_distances()  # _tree_part compiles the tree build meanwhile
    _broad_phase()
    _steps(SCHEMES)


def warm_scene() -> float:
    """Two steps of a small scene (two boxes stacked on a plane, touching; the default
    scheme): the kernels a process that will step scenes needs first — and Numba's own
    first-dispatch set-up — loaded now (from the cache, or compiled); its seconds. Lighter
    than :func:`warmup` (measured in fresh processes on a 2-vCPU VM from a warm cache: 0.54–0.69
    s and 198 MB peak against 1.0–1.1 s and 285 MB): a scene's Ray actor started ahead of its scene
    (``service.cluster.scenes``) calls it."""
    start = time.perf_counter()
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add_plane(size=2.0, divisions=1)
    scene.add_body(box(), position=(0.0, 0.0, 0.505))
    scene.add_body(box(), position=(0.0, 0.0, 1.505))  # on the first: body-body contacts
    for _ in range(2):  # the second reuses the first's contacts (warm start)
        scene.step(1e-3)
    return time.perf_counter() - start


#: The warm-up's parts, heaviest first.
PARTS = (_tree_part, _triangle_part)


def default_workers() -> int:
    """Processes :func:`warmup` uses by default: one when :func:`warm_stamp` exists (every
    kernel loads from the cache: another process would only load part of it again), else
    one per part, at most one per CPU."""
    if warm_stamp().exists():
        return 1
    return max(1, min(len(PARTS), os.cpu_count() or 1))


def warm_stamp() -> Path:
    """The file a completed :func:`warmup` leaves in the kernel cache directory
    (``numba.config.CACHE_DIR``, which already names the kernels' source hash); its name
    hashes this module's source, Python's and Numba's versions, so a new warm-up list or
    compiler does not count as warm."""
    digest = hashlib.sha256(Path(__file__).read_bytes())
    digest.update(f"{platform.python_version()} {numba.__version__}".encode())
    return Path(numba.config.CACHE_DIR) / f"warmup-{digest.hexdigest()[:16]}.done"


def _leave_stamp() -> None:
    stamp = warm_stamp()
    try:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.touch()
    except OSError:  # a read-only cache: every start then uses the default for a cold one
        pass


#: Garbage-collector thresholds while compiling. Numba's compiler allocates many objects
#: that outlive the youngest generation: with Python's default (700, 10, 10) the collector
#: took about 20 % of a cold warm-up's CPU time (measured: part 1 364 → 284 CPU-seconds,
#: peak memory 1.08 → 1.14 GB; with the collector off, 297 s and 2.2 GB).
COMPILE_GC_THRESHOLDS = (100_000, 20, 100)


@contextlib.contextmanager
def _compile_gc():
    """Raise the collector's thresholds to :data:`COMPILE_GC_THRESHOLDS`, then restore them."""
    before = gc.get_threshold()
    gc.set_threshold(*COMPILE_GC_THRESHOLDS)
    try:
        yield
    finally:
        gc.set_threshold(*before)


def _run_part(index: int) -> None:
    with _compile_gc():
        PARTS[index]()


def warmup(workers: int | None = None) -> float:
    """Run every kernel once on tiny inputs in both precisions; returns the seconds taken.

    Parameters
    ----------
    workers : processes compiling at once (this one included), 1 … ``len(PARTS)``;
        ``None``: :func:`default_workers` (1 once a warm-up has completed on this cache).
        Parts 1 … ``workers − 1`` first run in spawned processes, which share this
        process's ``NUMBA_CACHE_DIR``.
    """
    workers = default_workers() if workers is None else workers
    if not 1 <= workers <= len(PARTS):
        raise InvalidArgumentError(f"workers must be 1 … {len(PARTS)}, got {workers}")
    with _compile_gc():
        seconds = _warm(workers)
    _leave_stamp()
    return seconds


def _warm(workers: int) -> float:
    start = time.perf_counter()
    rest = PARTS
    if workers > 1:
        context = multiprocessing.get_context("spawn")  # no forked Numba or thread state
        with ProcessPoolExecutor(workers - 1, mp_context=context) as pool:
            others = [pool.submit(_run_part, i) for i in range(1, workers)]
            PARTS[0]()
            for done in others:
                done.result()  # a failure there is a failure here
        rest = PARTS[1:]
    for part in rest:  # compiled by another process (this one loads it), or here
        part()
    return time.perf_counter() - start
