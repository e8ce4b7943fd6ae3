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


def test_a_steps_idempotency_key_unpickles_without_serving():
    """A step's :class:`~service.store.Key` goes to the scene's actor, which unpickles it:
    that brings in no web framework (it was FastAPI, the codecs: 0.10–0.14 s of a spare
    actor's first step)."""
    import pickle

    from service.idempotency import Key

    sent = pickle.dumps(Key("k-1", "f" * 64))
    code = f"import pickle\nkey = pickle.loads({sent!r})\nprint(key.remember(200, {{}})[0])"
    assert imported(code, (*HEAVY, "starlette", "service.idempotency")) == ["k-1"]


def test_the_deployment_names_still_import():
    out = imported(
        "from service.cluster import APP_NAME, NAMESPACE, ActorScenes, Ingress, run\n"
        "import service.cluster.deployment as d\nassert run is d.run",
        HEAVY,
    )
    assert "ray.serve" in out and "service.cluster.deployment" in out
