"""service/cluster/deployment.py: a replica running below the default priority (Ray's
worker niceness, 15 unless the nodes say otherwise) says so, and what to do; the replicas'
count is fixed, or Serve's autoscaling between ``MRDEM_REPLICAS`` and ``MRDEM_REPLICAS_MAX``
with the settings' target, delays and window."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.cluster


def test_replicas_are_fixed_unless_a_larger_most_is_set():
    from service.cluster.deployment import scaling
    from service.settings import Settings

    assert scaling(Settings(), 3, 1.0) == {"num_replicas": 3, "max_ongoing_requests": 8}
    assert scaling(Settings(replicas=3, replicas_max=3), 3, 1.0)["num_replicas"] == 3
    settings = Settings(
        replicas=2,
        replicas_max=6,
        replica_target_requests=3,
        replica_upscale_delay=4,
        replica_downscale_delay=50,
        replica_load_window=7,
    )
    options = scaling(settings, 2, 4.0)
    assert "num_replicas" not in options and options["max_ongoing_requests"] == 16
    assert options["autoscaling_config"] == {
        "min_replicas": 2,
        "initial_replicas": 2,
        "max_replicas": 6,
        "target_ongoing_requests": 3,
        "upscale_delay_s": 4,
        "downscale_delay_s": 50,
        "look_back_period_s": 7,
    }


def test_a_target_a_replica_cannot_reach_is_refused_with_the_most_it_takes():
    from service.cluster.deployment import scaling
    from service.settings import Settings

    settings = Settings(replicas_max=2, replica_target_requests=9)
    with pytest.raises(ValueError, match="MRDEM_REPLICA_TARGET_REQUESTS .* set it to 8 or less"):
        scaling(settings, 1, 1.0)
    assert scaling(settings, 1, 3.0)["autoscaling_config"]["target_ongoing_requests"] == 9


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
