"""Geometry: validated and repaired meshes, shapes, poses and the triangle-distance host API."""

from engine.geometry import shapes
from engine.geometry.distance import (
    DEFAULT_ITERATIONS,
    DEFAULT_PRECISION,
    KernelStats,
    PairStatus,
    TriangleContacts,
    TriangleDistances,
    TriangleSet,
    triangle_contacts,
    triangle_distances,
)
from engine.geometry.mesh import MassProperties, Mesh, load_mesh
from engine.geometry.pose import Pose
from engine.geometry.repair import RepairReport, repair_mesh

__all__ = [
    "DEFAULT_ITERATIONS",
    "DEFAULT_PRECISION",
    "KernelStats",
    "MassProperties",
    "Mesh",
    "PairStatus",
    "Pose",
    "RepairReport",
    "TriangleContacts",
    "TriangleDistances",
    "TriangleSet",
    "load_mesh",
    "repair_mesh",
    "shapes",
    "triangle_contacts",
    "triangle_distances",
]
