"""The test layout (issue 14): tests mirror the engine's modules, and Hypothesis runs
derandomised in CI, and the import contracts in pyproject.toml hold (``lint-imports``, also
run by ``make lint``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("geometry", "trees", "collision", "dynamics")

NO_OWN_TEST = {
    "geometry/reference.py": "the slow oracle the distance tests compare the kernels with",
}
"""Modules without a test file of their own, and why."""

NOT_YET: set[str] = set()
"""Modules with logic still tested only through others (test_scene, test_dynamics,
test_picard): this list may only shrink."""


def test_every_engine_module_with_logic_has_its_test_file():
    modules = {
        f"{package}/{path.name}"
        for package in PACKAGES
        for path in (ROOT / "engine" / package).glob("*.py")
        if path.name != "__init__.py"
    }
    tested = {m for m in modules if (ROOT / "tests/engine" / mirror(m)).is_file()}
    assert set(NO_OWN_TEST) <= modules and modules >= NOT_YET, "a listed module is gone"
    missing = sorted(modules - tested - set(NO_OWN_TEST) - NOT_YET)
    assert not missing, f"no tests/engine/<package>/test_<module>.py for {missing}"
    done = sorted(NOT_YET & tested)
    assert not done, f"{done} have their test file now: take them off NOT_YET"


def mirror(module: str) -> str:
    package, name = module.split("/")
    return f"{package}/test_{name}"


# ------------------------------------------------------------------ Hypothesis profiles
PROBE = (
    "import sys; sys.path.insert(0, 'tests'); import conftest; "
    "from hypothesis import settings as s; d = s.default; "
    "print(d.derandomize, d.database is None, d.deadline, d.print_blob)"
)


@pytest.mark.parametrize(
    ("value", "expected"),
    [("true", True), ("1", True), ("yes", True), (None, False), ("", False), ("0", False)]
    + [("false", False), (" False ", False)],
)
def test_ci_is_set_by_any_value_but_empty_0_or_false(value, expected):
    from conftest import in_ci

    assert in_ci({} if value is None else {"CI": value}) is expected


def test_this_run_loaded_the_profile_its_environment_asks_for():
    from conftest import in_ci

    d = settings.default
    loaded = (d.derandomize, d.database is None, d.deadline, d.print_blob)
    ci = settings.get_profile("ci")
    dev = settings.get_profile("dev")
    wanted = ci if in_ci() else dev
    assert loaded == (
        wanted.derandomize,
        wanted.database is None,
        wanted.deadline,
        wanted.print_blob,
    )
    assert ci.derandomize and ci.database is None and ci.deadline is None and ci.print_blob
    assert not dev.derandomize


@pytest.mark.parametrize(("ci", "expected"), [("true", "True True None True"), (None, "False")])
def test_the_profile_is_loaded_on_import_of_the_test_configuration(ci, expected):
    """In a fresh process (the profile is chosen when conftest is imported)."""
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    if ci is not None:
        env["CI"] = ci
    out = subprocess.run(
        [sys.executable, "-c", PROBE], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1].startswith(expected)


def _examples(profile: str) -> list[int]:
    seen: list[int] = []

    @settings(settings.get_profile(profile), max_examples=20, database=None)
    @given(st.integers(0, 2**62))
    def record(x):
        seen.append(x)

    record()
    return seen


def test_the_ci_profile_draws_the_same_examples_every_run():
    assert _examples("ci") == _examples("ci")
    assert _examples("dev") != _examples("dev")  # fresh random examples each run


def test_the_import_contracts_hold():
    """clients -> service -> engine, mrdem_common neutral, the engine's layers, no cycles."""
    command = Path(sys.executable).with_name("lint-imports")
    assert command.exists(), "import-linter is a dev dependency: pip install -e '.[dev]'"
    result = subprocess.run(
        [str(command), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
