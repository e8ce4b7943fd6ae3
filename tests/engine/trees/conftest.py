"""The trees that several test modules of tests/engine/trees check: one per test mesh."""

from __future__ import annotations

import pytest

from engine import shapes
from engine.trees.build import build_tree

MESHES = {
    "icosphere": lambda: shapes.icosphere(2),
    "noisy_sphere": lambda: shapes.noisy_sphere(subdivisions=2, eta_r=1.4, seed=5),
    "stretched_sphere": lambda: shapes.stretched_sphere(subdivisions=2, eta=2.6),
    "torus": lambda: shapes.torus(major_segments=24, minor_segments=10),
    "box": lambda: shapes.box(extents=(2.0, 1.0, 0.5)),
    "plane": lambda: shapes.plane(size=(4.0, 4.0), divisions=6),
}


@pytest.fixture(scope="session", params=sorted(MESHES))
def built(request):
    """(mesh, its tree at ε 0.01, branching 8, seed 1) for each of :data:`MESHES`."""
    mesh = MESHES[request.param]()
    return mesh, build_tree(mesh, epsilon=0.01, branching=8, seed=1)
