"""mrdem engine: meshes, shapes, triangle-distance kernels (pure computation).

Never imports ``service`` or ``clients``.
"""

from . import shapes
from .errors import EngineError, InvalidArgumentError, InvalidMeshError
from .mesh import MassProperties, Mesh, load_mesh

__all__ = [
    "EngineError",
    "InvalidArgumentError",
    "InvalidMeshError",
    "MassProperties",
    "Mesh",
    "load_mesh",
    "shapes",
]
