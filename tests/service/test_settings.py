"""Settings from ``MRDEM_*`` and the ``mrdem`` command line."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from service import Settings
from service.cli import main


def test_settings_from_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("MRDEM_PORT", "9123")
    monkeypatch.setenv("MRDEM_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("MRDEM_API_KEYS", " first-key-1 ,second-key-2,, ")
    monkeypatch.setenv("MRDEM_MAX_PAIRS", "17")
    monkeypatch.setenv("MRDEM_WARMUP_WORKERS", "1")
    s = Settings()
    assert s.port == 9123 and s.data_dir == tmp_path and s.max_pairs == 17
    assert s.warmup_workers == 1
    assert s.api_keys == ("first-key-1", "second-key-2")
    assert s.host == "127.0.0.1"


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("MRDEM_API_KEYS", "short"),
        ("MRDEM_PORT", "70000"),
        ("MRDEM_MAX_STEPS", "0"),
        ("MRDEM_WARMUP_WORKERS", "3"),
    ],
)
def test_bad_settings_are_refused(monkeypatch, name, value):
    monkeypatch.setenv(name, value)
    with pytest.raises(ValidationError):
        Settings()


def test_the_most_replicas_is_unset_or_at_least_the_fewest(monkeypatch):
    monkeypatch.setenv("MRDEM_REPLICAS", "3")
    monkeypatch.setenv("MRDEM_REPLICAS_MAX", "")  # compose's default when the operator sets none
    assert Settings().replicas_max is None
    monkeypatch.setenv("MRDEM_REPLICAS_MAX", "3")
    assert Settings().replicas_max == 3
    monkeypatch.setenv("MRDEM_REPLICAS_MAX", "2")
    with pytest.raises(ValidationError, match=r"MRDEM_REPLICAS_MAX \(2\) is below MRDEM_REPLICAS"):
        Settings()


def test_command_line_lists_serve(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "serve" in capsys.readouterr().out
    assert main(["info"]) == 0
    assert '"numba"' in capsys.readouterr().out
