"""The README's remote simulation loop runs as written against a real service."""

from __future__ import annotations

from harness import run_readme_loop


def test_readme_remote_loop(live_service, monkeypatch, capsys):
    run_readme_loop(live_service.url, monkeypatch, capsys)
