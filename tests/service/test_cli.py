"""``mrdem bench``: each script's output in a log, failures counted."""

from __future__ import annotations

from service.cli import bench


def test_bench_runs_each_script_and_counts_failures(tmp_path, capsys):
    folder = tmp_path / "benchmarks"
    folder.mkdir()
    (folder / "kernels.py").write_text("import sys\nprint('table', sys.argv[1:])\n")
    (folder / "trees.py").write_text("raise SystemExit(3)\n")
    assert bench(["kernels", "trees"], quick=True, root=tmp_path) == 1
    assert "table ['--quick']" in (tmp_path / "bench-results" / "kernels.log").read_text()
    out = capsys.readouterr().out
    assert "kernels: ok" in out and "trees: FAILED (3)" in out and "1/2 benchmarks" in out
