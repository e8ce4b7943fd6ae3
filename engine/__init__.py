"""mrdem engine: meshes, surrogate trees, contact search and rigid-body dynamics (pure computation).

Sub-packages by concern, each calling only those below it: :mod:`engine.geometry` (meshes,
shapes, poses, triangle distances), :mod:`engine.trees` (surrogate trees),
:mod:`engine.collision` (broad phase, contact searches, batches, proximity),
:mod:`engine.dynamics` (force laws, mass properties, Picard, sleep), with
:mod:`engine.scene` composing them; :mod:`engine.kernels` holds their Numba kernels.
Never imports ``service`` or ``clients``.
"""

from engine import scenarios
from engine.arguments import KERNELS, PRECISIONS
from engine.collision import (
    ContactBatch,
    ContactSet,
    ContactStats,
    MeshDistance,
    PairCache,
    TreeBank,
    candidate_pairs,
    find_contacts,
    find_contacts_batch,
    mesh_distance,
)
from engine.dynamics import (
    DEFAULT_SEPARATION_SPEED,
    ContactModel,
    HertzSpring,
    LinearSpring,
    OverlapReport,
    PaperSpring,
    StepStats,
    TunnellingWarning,
)
from engine.dynamics.inertia import check_inertia
from engine.errors import EngineError, InvalidArgumentError, InvalidMeshError
from engine.geometry import (
    DEFAULT_ITERATIONS,
    DEFAULT_PRECISION,
    KernelStats,
    MassProperties,
    Mesh,
    PairStatus,
    Pose,
    RepairReport,
    TriangleContacts,
    TriangleDistances,
    TriangleSet,
    load_mesh,
    repair_mesh,
    shapes,
    triangle_contacts,
    triangle_distances,
)
from engine.scene import DEFAULT_SCHEME, SCHEMES, Scene, SceneState
from engine.trees import TREE_FORMAT, SurrogateTree, TreeStats, build_tree, size_epsilon
from engine.trees.halos import AUTO as AUTO_EPSILON
from engine.warmup import warm_scene, warmup

__all__ = [
    "AUTO_EPSILON",
    "KERNELS",
    "PRECISIONS",
    "TREE_FORMAT",
    "check_inertia",
    "ContactSet",
    "ContactStats",
    "Pose",
    "find_contacts",
    "ContactBatch",
    "candidate_pairs",
    "ContactModel",
    "HertzSpring",
    "LinearSpring",
    "OverlapReport",
    "PaperSpring",
    "SCHEMES",
    "DEFAULT_SCHEME",
    "DEFAULT_SEPARATION_SPEED",
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
    "warm_scene",
    "warmup",
    "EngineError",
    "InvalidArgumentError",
    "InvalidMeshError",
    "MassProperties",
    "Mesh",
    "SurrogateTree",
    "build_tree",
    "size_epsilon",
    "load_mesh",
    "RepairReport",
    "repair_mesh",
    "MeshDistance",
    "mesh_distance",
    "scenarios",
    "shapes",
]
