"""Compile the kernels cold on a many-core machine in one process per kernel family.

``engine.warmup()`` compiles in at most two processes (its two parts): on the 16-core
device machine, whose compiles run about twice as slow as the 2-vCPU VM's, that is minutes
of a lease. This script compiles the same kernels in up to 12 spawned processes at once
(the batched search per precision, the single searches, the triangle sets, and one step of
each scheme; kernels two families share are compiled twice, in parallel), all writing the
shared ``$NUMBA_CACHE_DIR``, then runs ``engine.warmup(1)`` here, which loads them (and
compiles anything they missed) and leaves the warm stamp. On the 2-vCPU VM, 2 processes, a
first version that compiled the batch once per kernel took 227 s, then 1.5 s for the
warm-up (all loaded). Prints the seconds of each step. Used by
``benchmarks/device/run.sh``; no part of the service.

    python3 benchmarks/device/warm_wide.py [--workers N]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

import numpy as np

import engine
from engine.arguments import KERNELS, PRECISIONS
from engine.collision.batch import find_contacts_batch
from engine.collision.broadphase import SMALL_SCENE, CandidateList, candidate_pairs
from engine.collision.contacts import find_contacts
from engine.collision.proximity import mesh_distance
from engine.dynamics.picard import TunnellingWarning
from engine.geometry.distance import TriangleSet, triangle_contacts, triangle_distances
from engine.geometry.pose import Pose
from engine.geometry.shapes import box
from engine.scene import SCHEMES, Scene
from engine.trees.build import build_tree
from engine.trees.surrogates import FITS

NEAR = ([0.9, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])


def _batch(precision: str) -> None:
    tree = build_tree(box(), 0.05)
    pair = (tree, Pose.identity(), tree, Pose(*NEAR))
    for kernel in KERNELS:  # one compile: the kernel is an argument of the batch kernel
        find_contacts_batch([pair], kernel=kernel, precision=precision)


def _single(precision: str) -> None:
    tree = build_tree(box(), 0.05)
    for kernel in KERNELS:
        for hierarchy in (True, False):
            find_contacts(
                tree,
                Pose.identity(),
                tree,
                Pose(*NEAR),
                kernel=kernel,
                hierarchy=hierarchy,
                precision=precision,
            )


def _triangles(precision: str) -> None:
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 0, 1], [0, 1, 1]]], float)
    sets = TriangleSet(tri, precision)
    TriangleSet(tri.astype(precision), precision)
    for kernel in KERNELS:
        triangle_distances(sets, sets, kernel, precision, 0.1, threads=1)
        triangle_distances(tri, tri, kernel, precision, 0.1, threads=1)
        if precision == "float32":
            triangle_distances(
                tri.astype(np.float32), tri.astype(np.float32), kernel, precision, 0.1, threads=1
            )
        triangle_contacts(sets, sets, 0.1, 0.1, kernel=kernel, precision=precision, threads=1)
        triangle_contacts(
            sets, sets, 0.1, 0.1, pairs=[[0, 1]], kernel=kernel, precision=precision, threads=1
        )


def _fits_and_broad_phase() -> None:
    for fit in FITS:
        build_tree(box(), 0.05, fit=fit)
    tree = build_tree(box(), 0.05)
    for precision in PRECISIONS:
        mesh_distance(tree, Pose.identity(), tree, Pose(*NEAR), precision=precision)
    many = np.arange(3 * (SMALL_SCENE + 1), dtype=float).reshape(-1, 3)
    candidate_pairs(many, np.ones(len(many)), np.zeros(len(many), bool))
    kept = CandidateList()
    for _ in range(2):
        kept.pairs(many, np.ones(len(many)), np.zeros(len(many), bool))


def _step(scheme: str) -> None:
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add_plane(size=4.0, divisions=2)
    scene.add_body(box(), position=(0.0, 0.0, 0.505), angular_velocity=(0.0, 0.0, 1.0))
    scene.add_body(box(), position=(0.3, 0.0, 1.52))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TunnellingWarning)
        scene.step(1e-3, scheme)


#: (name, function, arguments), heaviest first.
JOBS = (
    *((f"batch {p}", _batch, (p,)) for p in reversed(PRECISIONS)),
    *((f"step {s}", _step, (s,)) for s in SCHEMES),
    *((f"single {p}", _single, (p,)) for p in PRECISIONS),
    *((f"triangles {p}", _triangles, (p,)) for p in PRECISIONS),
    ("fits, mesh_distance, broad phase", _fits_and_broad_phase, ()),
)


def _run(index: int) -> tuple[str, float]:
    name, function, arguments = JOBS[index]
    start = time.perf_counter()
    function(*arguments)
    return name, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=min(len(JOBS), os.cpu_count() or 1))
    args = parser.parse_args()
    start = time.perf_counter()
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(args.workers, mp_context=context) as pool:
        for name, seconds in pool.map(_run, range(len(JOBS))):
            print(f"{name}: {seconds:.1f} s", flush=True)
    wide = time.perf_counter() - start
    loaded = engine.warmup(1)
    print(f"{len(JOBS)} jobs, {args.workers} processes: {wide:.1f} s; warmup(1) {loaded:.1f} s")


if __name__ == "__main__":
    main()
