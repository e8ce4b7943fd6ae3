"""A package's names loaded on first use (PEP 562's module ``__getattr__``).

A package whose ``__init__`` imports its heavy modules makes every process that imports any
of its modules pay for all of them: a scene's actor or a contacts task on a Ray node
imports ``service.cluster.scenes``, hence ``service/__init__`` and ``service/cluster/__init__``
(FastAPI, every router, Ray Serve): ``import service.cluster.batches`` took 1.9–2.0 s on a
2-vCPU VM, 0.7 s with the packages' names loaded on first use (and the engine's trimesh).
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["attributes"]


def attributes(package: str, homes: dict[str, str]) -> Callable[[str], Any]:
    """The ``__getattr__`` of ``package`` (its ``__name__``): each name of ``homes`` (name →
    the module holding it, relative to the package: ``".app"``) is imported from its module
    on first use and kept in the package (later lookups do not reach the hook); any other
    name is an ``AttributeError``, as for a plain module."""

    def __getattr__(name: str) -> Any:
        if name not in homes:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(homes[name], package), name)
        setattr(sys.modules[package], name, value)
        return value

    return __getattr__
