"""The README's remote simulation loop runs as written against a real service."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_remote_loop(live_service, monkeypatch, capsys):
    (block,) = re.findall(r"```python remote\n(.*?)```", README.read_text(), re.S)
    monkeypatch.setenv("MRDEM_URL", live_service.url)
    namespace: dict = {}
    exec(compile(block, str(README), "exec"), namespace)  # noqa: S102
    state = namespace["state"]
    assert state.steps == 400 and state.positions.shape == (2, 3)
    assert 0.3 < state.positions[0, 0] < 0.45  # it rolled, then was stopped
    assert abs(state.positions[0, 2] - 0.5) < 0.02  # resting on the plane
    assert "ball at" in capsys.readouterr().out
