"""The README's tour runs as written."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_tour_runs():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert blocks, "README has no python block"
    namespace: dict = {}
    for block in blocks:  # in order, one namespace: later blocks use earlier names
        exec(compile(block, str(README), "exec"), namespace)  # noqa: S102
    assert len(namespace["hits"].pairs) > 0  # the posed spheres overlap
    assert namespace["stats"].converged and len(namespace["grid"]) == 8
