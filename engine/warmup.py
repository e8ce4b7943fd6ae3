"""Compile (or load from the cache) every kernel, as the service does before it is ready."""

from __future__ import annotations

import time
import warnings

import numpy as np

from engine.arguments import KERNELS, PRECISIONS
from engine.collision.batch import find_contacts_batch
from engine.collision.broadphase import SMALL_SCENE, candidate_pairs
from engine.collision.contacts import find_contacts
from engine.dynamics.picard import TunnellingWarning
from engine.geometry.distance import TriangleSet, triangle_contacts, triangle_distances
from engine.geometry.pose import Pose
from engine.geometry.shapes import box
from engine.scene import SCHEMES, Scene
from engine.trees.build import build_tree
from engine.trees.surrogates import FITS

__all__ = ["warmup"]


def warmup() -> float:
    """Run every kernel once on tiny inputs in both precisions; returns the seconds taken."""
    start = time.perf_counter()
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 0, 1], [0, 1, 1]]], float)
    for fit in FITS:  # "epsilon" and "paper" run the surrogate_fit kernels
        build_tree(box(), 0.05, fit=fit)
    tree = build_tree(box(), 0.05)
    near = Pose([0.9, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
    for precision in PRECISIONS:
        sa = TriangleSet(tri, precision)
        for kernel in KERNELS:
            triangle_distances(sa, sa, kernel, precision, 0.1, threads=1)
            triangle_contacts(sa, sa, 0.1, 0.1, kernel=kernel, precision=precision, threads=1)
            triangle_contacts(
                sa, sa, 0.1, 0.1, pairs=[[0, 1]], kernel=kernel, precision=precision, threads=1
            )
            find_contacts_batch(
                [(tree, Pose.identity(), tree, near)], kernel=kernel, precision=precision
            )
            for hierarchy in (True, False):
                find_contacts(
                    tree,
                    Pose.identity(),
                    tree,
                    near,
                    kernel=kernel,
                    hierarchy=hierarchy,
                    precision=precision,
                )
    many = np.arange(3 * (SMALL_SCENE + 1), dtype=float).reshape(-1, 3)  # the grid path
    candidate_pairs(many, np.ones(len(many)), np.zeros(len(many), bool))
    scene = Scene(gravity=(0.0, 0.0, -9.81))  # broad phase, forces, motion update
    scene.add_plane(size=4.0, divisions=2)
    scene.add_body(box(), position=(0.0, 0.0, 0.505), angular_velocity=(0.0, 0.0, 1.0))
    scene.add_body(box(), position=(0.3, 0.0, 1.52))
    with warnings.catch_warnings():  # a synthetic scene: its fast spin may warn of tunnelling
        warnings.simplefilter("ignore", TunnellingWarning)
        for scheme in SCHEMES:
            scene.step(1e-3, scheme)
    return time.perf_counter() - start
