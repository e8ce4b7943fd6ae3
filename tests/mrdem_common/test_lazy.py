"""mrdem_common.lazy: a package's names imported on first use, in a fresh process."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _package(tmp_path: Path) -> Path:
    """A package ``pkg`` whose ``heavy`` module records its import, named lazily."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        textwrap.dedent(
            """
            from mrdem_common.lazy import attributes
            __getattr__ = attributes(__name__, {"Heavy": ".heavy", "missing": ".heavy"})
            """
        )
    )
    (pkg / "heavy.py").write_text(
        "import builtins\nbuiltins.heavy_imports = getattr(builtins, 'heavy_imports', 0) + 1\n"
        "class Heavy:\n    pass\n"
    )
    (pkg / "light.py").write_text("LIGHT = 1\n")
    return tmp_path


def _run(path: Path, code: str) -> str:
    env_path = f"{path}:{ROOT}"
    result = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        env={"PYTHONPATH": env_path, "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    return result.stdout.strip()


def test_a_name_is_imported_on_first_use_once_and_kept(tmp_path):
    out = _run(
        _package(tmp_path),
        """
        import builtins, sys
        import pkg.light
        print(getattr(builtins, "heavy_imports", 0), "pkg.heavy" in sys.modules)
        first = pkg.Heavy
        print(builtins.heavy_imports, first is pkg.Heavy, "Heavy" in vars(pkg))
        from pkg import Heavy
        print(builtins.heavy_imports, Heavy is first)
        """,
    )
    assert out.splitlines() == ["0 False", "1 True True", "1 True"]


def test_an_unknown_name_is_an_attribute_error(tmp_path):
    out = _run(
        _package(tmp_path),
        """
        import pkg
        for name in ("nothing", "missing"):  # "missing": listed, but not in its module
            try:
                getattr(pkg, name)
            except AttributeError as error:
                print(type(error).__name__, error)
        print(hasattr(pkg, "nothing"))
        """,
    )
    lines = out.splitlines()
    assert lines[0] == "AttributeError module 'pkg' has no attribute 'nothing'"
    assert lines[1].startswith("AttributeError") and "missing" in lines[1]
    assert lines[2] == "False"
