"""service/cluster/deployment.py: a replica running below the default priority (Ray's
worker niceness, 15 unless the nodes say otherwise) says so, and what to do."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.cluster

PROBE = "from service.cluster.deployment import niceness_warning; print(niceness_warning())"


@pytest.mark.parametrize("nice", [0, 15])
def test_a_process_below_the_default_priority_is_told_how_to_raise_it(nice):
    """The same check a replica's constructor makes, in a process started at ``nice``."""
    command = [sys.executable, "-c", PROBE]
    if nice:
        command = ["nice", "-n", str(nice), *command]
    found = subprocess.run(command, capture_output=True, text=True, timeout=120, check=True)
    said, runs_at = found.stdout.strip(), min(os.nice(0) + nice, 19)  # nice adds to ours
    if runs_at == 0:
        assert said == "None"
    else:
        assert f"runs at nice {runs_at}" in said and "RAY_worker_niceness=0" in said
