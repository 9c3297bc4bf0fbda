"""A log folder's YAML (rl-zoo3's ``config.yml`` / ``args.yml``) is data, never code: rl-zoo3 reads
it with ``yaml.UnsafeLoader``, ``python -m sb3_coma.zoo enjoy`` with a loader that knows plain YAML
and rl-zoo3's ``OrderedDict`` only."""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import pytest
import yaml

from sb3_coma.app.config import TrainingError
from sb3_coma.app.zoo import _enjoy_env_kwargs, read_zoo_log_yaml


def test_rl_zoo3s_ordered_dicts_load_as_data(tmp_path: Path) -> None:
    path = tmp_path / "args.yml"
    written = OrderedDict([("env_kwargs", {"fusion": "mean", "n_uavs": 2}), ("seed", 3), ("algo", "coma")])
    path.write_text(yaml.dump(written))  # what rl-zoo3's ExperimentManager writes
    assert read_zoo_log_yaml(path) == written


def test_a_python_object_tag_is_refused_and_never_run(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    log = tmp_path / "logs" / "UavIpp-Env1-v0"
    log.mkdir(parents=True)
    (log / "args.yml").write_text(
        f'env_kwargs: !!python/object/apply:builtins.exec ["open({str(marker)!r}, \\"w\\")"]\n'
    )
    with pytest.raises(TrainingError, match=r"args.yml: .*python/object/apply:builtins.exec.*never Python objects"):
        _enjoy_env_kwargs(str(tmp_path / "logs"), "UavIpp-Env1-v0", {}, None)
    assert not marker.exists()
