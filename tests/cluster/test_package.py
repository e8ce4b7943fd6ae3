"""service/cluster/__init__.py: what Ray imports to start a scene's actor or a contacts task
(:mod:`service.cluster.scenes`, :mod:`service.cluster.batches`) brings in neither Ray Serve
nor FastAPI nor the app — about a second of each such process's start, measured — checked in
a fresh process; the package's names still import."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.cluster

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("ray.serve", "fastapi", "service.app", "service.cluster.deployment", "trimesh")


def _imported(code: str) -> list[str]:
    probe = f"{code}\nimport sys\nprint(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    found = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert found.returncode == 0, found.stderr
    return found.stdout.split()


@pytest.mark.parametrize("module", ["service.cluster.scenes", "service.cluster.batches"])
def test_an_actor_or_a_task_imports_no_serving(module):
    assert _imported(f"import {module}") == []


def test_the_deployment_names_still_import():
    out = _imported(
        "from service.cluster import APP_NAME, NAMESPACE, ActorScenes, Ingress, run\n"
        "import service.cluster.deployment as d\nassert run is d.run"
    )
    assert "ray.serve" in out and "service.cluster.deployment" in out
