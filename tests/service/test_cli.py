"""``mrdem bench``: each script's output in a log, failures counted; ``mrdem upload``;
``mrdem serve`` and ``python -m service`` with settings they cannot use: each problem with
its variable, no traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest
import trimesh

from service.cli import bench, main


def test_bench_runs_each_script_and_counts_failures(tmp_path, capsys):
    folder = tmp_path / "benchmarks"
    folder.mkdir()
    (folder / "kernels.py").write_text("import sys\nprint('table', sys.argv[1:])\n")
    (folder / "trees.py").write_text("raise SystemExit(3)\n")
    assert bench(["kernels", "trees"], quick=True, root=tmp_path) == 1
    assert "table ['--quick']" in (tmp_path / "bench-results" / "kernels.log").read_text()
    out = capsys.readouterr().out
    assert "kernels: ok" in out and "trees: FAILED (3)" in out and "1/2 benchmarks" in out


def test_upload_runs_the_client_program(live_service, tmp_path, capfd):
    """``mrdem upload`` is the client's program in its own process (service never imports
    clients): it uploads, waits and prints the mesh."""
    path = tmp_path / "box.obj"
    trimesh.creation.box(extents=(1.0, 2.0, 0.5)).export(path)
    assert main(["upload", str(path), "--url", live_service.url, "--epsilon", "0.01"]) == 0
    out = capfd.readouterr().out
    assert "box.obj: " in out and "12 triangles" in out and "watertight" in out
    missing = tmp_path / "missing.stl"
    assert main(["upload", str(missing), "--url", live_service.url]) == 1
    assert "missing.stl" in capfd.readouterr().out


@pytest.mark.parametrize(
    ("variable", "value", "said"),
    [
        ("MRDEM_PORT", "eighty", "MRDEM_PORT: Input should be a valid integer"),
        ("MRDEM_MAX_PAIRS", "0", "MRDEM_MAX_PAIRS: Input should be greater than or equal to 1"),
        ("MRDEM_STORE_URL", "mysql://db", "MRDEM_STORE_URL: Value error, the store URL is a"),
    ],
)
def test_serve_names_the_settings_it_cannot_use(monkeypatch, capsys, variable, value, said):
    monkeypatch.setenv(variable, value)
    assert main(["serve"]) == 2
    assert said in capsys.readouterr().err


def test_python_m_service_refuses_bad_settings_without_a_traceback(tmp_path):
    env = {"MRDEM_REPLICAS": "0", "MRDEM_DATA_DIR": str(tmp_path), "PATH": "/usr/bin:/bin"}
    refused = subprocess.run(
        [sys.executable, "-m", "service"], env=env, capture_output=True, text=True, timeout=120
    )
    assert refused.returncode == 2
    assert "mrdem serve: MRDEM_REPLICAS: Input should be greater" in refused.stderr
    assert "Traceback" not in refused.stderr
