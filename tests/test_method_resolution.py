"""A method is resolved once (``sb3_coma.app.methods.resolve_method``) and trusted below the front door."""

from __future__ import annotations

import warnings

import pytest

from sb3_coma.app import evaluation as ev
from sb3_coma.app import pretrained
from sb3_coma.app.methods import Method, resolve_method


def _shipped_or_skip() -> None:
    try:
        pretrained.model_path("env3", verify=False)
    except pretrained.PretrainedError:
        pytest.skip("no shipped models in this install")


@pytest.mark.parametrize("given", ["path", "name"])
def test_evaluate_hashes_a_shipped_zip_once(monkeypatch: pytest.MonkeyPatch, given: str) -> None:
    """Two batches of missions, one SHA-256 of the shipped zip: resolved once, loaded per batch."""
    _shipped_or_skip()
    calls: list[object] = []
    real = pretrained.sha256_file

    def counting(path: object) -> str:
        calls.append(path)
        return real(path)  # type: ignore[arg-type]

    monkeypatch.setattr(pretrained, "sha256_file", counting)
    policy = str(pretrained.model_path("env3", verify=False)) if given == "path" else "env3"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ev.WorldMismatchWarning)  # budget 2: a shorter world than trained
        result = ev.evaluate(policy, env="env3", n_trials=4, n_envs=2, budget=2, record=0, workers=1)
    assert result.n_trials == 4
    assert len(calls) == 1, calls


def test_a_protocol_row_is_the_same_type_and_resolves_once() -> None:
    from sb3_coma.experiments import protocols

    assert protocols.Method is Method is ev.Method
    row = Method("ag-k2", "ag", planner_kwargs={"lookahead": 2})
    method = resolve_method(row)
    assert (method.source, method.label, method.kind, dict(method.planner_kwargs)) == (
        "planner",
        "ag-k2",
        "baseline",
        {"lookahead": 2},
    )
    assert resolve_method(method) == method  # a resolved method is trusted as it is
    reference = resolve_method(Method("ag-central", "ag-central", kind="reference"))
    assert reference.kind == "reference" and dict(reference.planner_kwargs) == {"knowledge": "central"}


def test_names_resolve_to_their_kind() -> None:
    alias = resolve_method("AG-K3")
    assert (alias.label, alias.policy, dict(alias.planner_kwargs)) == ("ag-k3", "ag", {"lookahead": 3})
    assert resolve_method("nl").policy == "lawnmower" and not resolve_method("nl").learned
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        resolve_method("nope")
    with pytest.raises(FileNotFoundError, match=r"model file not found: 'runs/nope\.zip'"):
        resolve_method("runs/nope.zip")
    with pytest.raises(TypeError, match="cannot evaluate int"):
        resolve_method(3)
