"""service/cluster/__init__.py: what Ray imports to start a scene's actor or a contacts task
(:mod:`service.cluster.scenes`, :mod:`service.cluster.batches`) brings in neither Ray Serve
nor FastAPI nor the app — about a second of each such process's start, measured — checked in
a fresh process; the package's names still import."""

from __future__ import annotations

import pytest
from harness import imported

pytestmark = pytest.mark.cluster

HEAVY = ("ray.serve", "fastapi", "service.app", "service.cluster.deployment", "trimesh")


@pytest.mark.parametrize("module", ["service.cluster.scenes", "service.cluster.batches"])
def test_an_actor_or_a_task_imports_no_serving(module):
    assert imported(f"import {module}", HEAVY) == []


def test_the_deployment_names_still_import():
    out = imported(
        "from service.cluster import APP_NAME, NAMESPACE, ActorScenes, Ingress, run\n"
        "import service.cluster.deployment as d\nassert run is d.run",
        HEAVY,
    )
    assert "ray.serve" in out and "service.cluster.deployment" in out
