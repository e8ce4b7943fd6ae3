"""mrdem engine: meshes, shapes, triangle-distance kernels, surrogate trees (pure computation).

Never imports ``service`` or ``clients``.
"""

from . import scenarios, shapes
from .batch import ContactBatch, PairCache, TreeBank, find_contacts_batch
from .broadphase import candidate_pairs
from .contacts import ContactSet, ContactStats, find_contacts
from .distance import (
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
from .errors import EngineError, InvalidArgumentError, InvalidMeshError
from .forces import ContactModel, HertzSpring, LinearSpring, PaperSpring
from .mesh import MassProperties, Mesh, load_mesh
from .picard import StepStats, TunnellingWarning
from .pose import Pose
from .proximity import MeshDistance, mesh_distance
from .repair import RepairReport, repair_mesh
from .scene import DEFAULT_SCHEME, SCHEMES, Scene, SceneState
from .tree import SurrogateTree, TreeStats, build_tree
from .warmup import warmup

__all__ = [
    "ContactSet",
    "ContactStats",
    "Pose",
    "find_contacts",
    "ContactBatch",
    "candidate_pairs",
    "ContactModel",
    "HertzSpring",
    "LinearSpring",
    "PaperSpring",
    "SCHEMES",
    "DEFAULT_SCHEME",
    "Scene",
    "SceneState",
    "StepStats",
    "TunnellingWarning",
    "PairCache",
    "TreeBank",
    "find_contacts_batch",
    "DEFAULT_ITERATIONS",
    "DEFAULT_PRECISION",
    "KernelStats",
    "PairStatus",
    "TriangleContacts",
    "TriangleDistances",
    "TreeStats",
    "TriangleSet",
    "triangle_contacts",
    "triangle_distances",
    "warmup",
    "EngineError",
    "InvalidArgumentError",
    "InvalidMeshError",
    "MassProperties",
    "Mesh",
    "SurrogateTree",
    "build_tree",
    "load_mesh",
    "RepairReport",
    "repair_mesh",
    "MeshDistance",
    "mesh_distance",
    "scenarios",
    "shapes",
]
