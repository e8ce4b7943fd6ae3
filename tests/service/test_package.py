"""service/__init__.py: its names load on first use, so that a process using part of the
service (a scene's actor, a contacts task on a Ray node) starts without FastAPI, the
routers or trimesh — each checked in a fresh process."""

from __future__ import annotations

import pytest
from harness import imported

HEAVY = ("fastapi", "starlette", "service.app", "service.routers", "trimesh", "scipy.spatial")


@pytest.mark.parametrize(
    "code",
    [
        "import engine",
        "import service.scenes, service.store, service.settings, service.search",
        "from service.errors import NotFound, Unavailable",
        "import service.cluster",  # Ray not needed to import the package
    ],
)
def test_the_parts_a_worker_needs_import_alone(code):
    assert imported(code, HEAVY) == []


def test_the_package_names_still_import():
    """The lazy names are the modules' own; the app then brings FastAPI in."""
    out = imported(
        "import service, service.app, service.cli, service.settings\n"
        "assert service.create_app is service.app.create_app\n"
        "assert service.serve is service.cli.serve\n"
        "assert service.Settings is service.settings.Settings\n"
        "from service import Settings, create_app, serve",
        HEAVY,
    )
    assert "fastapi" in out and "service.app" in out


def test_a_mesh_file_is_read_with_trimesh_imported_then(tmp_path):
    """engine.load_mesh imports trimesh where it reads (no longer at the engine's import)."""
    path = tmp_path / "tetra.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    code = f"import engine\nmesh = engine.load_mesh({str(path)!r})\nprint(mesh.n_faces)"
    out = imported(code, HEAVY)
    assert out[0] == "4" and "trimesh" in out
