"""A config file's YAML: a key written twice in one mapping is one line naming it (PyYAML keeps
the last silently); merge keys still merge and may be overridden."""

from __future__ import annotations

from pathlib import Path

import pytest

from sb3_coma.app.config import TrainingError, read_config_file


def test_a_key_written_twice_is_named_with_its_lines(tmp_path: Path) -> None:
    path = tmp_path / "coma.yml"
    path.write_text("UavIpp-Env1-v0:\n  n_timesteps: 100\n  learning_rate: 1e-4\n  learning_rate: 3e-4\n")
    with pytest.raises(
        TrainingError, match=r"line 4, column 3: key 'learning_rate' is written twice \(lines 3 and 4\)"
    ):
        read_config_file(path)
    path.write_text("UavIpp-Env1-v0: {n_timesteps: 1}\nUavIpp-Env1-v0: {n_timesteps: 2}\n")
    with pytest.raises(TrainingError, match=r"key 'UavIpp-Env1-v0' is written twice"):
        read_config_file(path)


def test_merge_keys_still_merge_and_override(tmp_path: Path) -> None:
    path = tmp_path / "coma.yml"
    path.write_text("base: &b\n  a: 1\n  b: 2\nx:\n  <<: *b\n  a: 3\n")
    assert read_config_file(path) == {"base": {"a": 1, "b": 2}, "x": {"a": 3, "b": 2}}


def test_the_shipped_config_has_no_key_twice() -> None:
    from sb3_coma.app.config import default_config_path

    assert "UavIpp-Env3-v0" in read_config_file(default_config_path())
