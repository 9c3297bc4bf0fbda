"""``fusion="sendfuse"``: the env wrapper around the shipped SenDFuse weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import uav_ipp
from sb3_coma.sendfuse.network import SenDFuseNet
from sb3_coma.sendfuse.weights import SenDFuseWeightsError, load_weights
from sb3_coma.sendfuse.wrapper import SenDFuseFusionWrapper
from uav_ipp import ConfigError, fusion, layout


def _random_actions(obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
    return np.array([rng.choice(np.flatnonzero(mask)) for mask in obs[layout.KEY_MASK]])


class CountingNet(SenDFuseNet):
    """The shipped network, counting ``fuse`` calls and the fusions per call."""

    def __init__(self) -> None:
        shipped = load_weights()
        super().__init__(grid_size=shipped.grid_size, channels=shipped.channels)
        self.load_state_dict(shipped.state_dict())
        self.calls: list[int] = []

    def fuse(self, maps, valid, alpha=None):  # type: ignore[override]
        self.calls.append(int(maps.shape[0]))
        return super().fuse(maps, valid, alpha)


def test_observation_space_equals_the_mean_wrappers() -> None:
    sendfuse = uav_ipp.make_vec_env("env3", fusion="sendfuse", seed=0)
    mean = uav_ipp.make_vec_env("env3", fusion="mean", seed=0)
    assert sendfuse.observation_space == mean.observation_space
    assert sendfuse.action_space == mean.action_space
    obs = sendfuse.reset()
    assert set(obs) == set(mean.observation_space.spaces)
    assert obs[layout.KEY_LOCAL].shape == (4, layout.LOCAL_CHANNELS, 11, 11)


def test_fused_channel_is_finite_and_in_unit_range() -> None:
    venv = uav_ipp.make_vec_env("env3", n_envs=2, fusion="sendfuse", seed=1, noise="loud", budget=5)
    rng = np.random.default_rng(0)
    obs = venv.reset()
    for _ in range(7):  # crosses an episode end (auto-reset, terminal observations fused too)
        fused = obs[layout.KEY_LOCAL][:, layout.FUSED]
        assert np.isfinite(fused).all() and fused.min() >= 0.0 and fused.max() <= 1.0
        assert venv.observation_space.contains({k: v[0] for k, v in obs.items()})
        obs, _, dones, infos = venv.step(_random_actions(obs, rng))
        for done, info in zip(dones, infos):
            if done:
                terminal = info["terminal_observation"][layout.KEY_LOCAL]
                assert terminal.shape == (layout.LOCAL_CHANNELS, 11, 11)
                assert terminal[layout.FUSED].min() >= 0.0 and terminal[layout.FUSED].max() <= 1.0


def test_without_noise_and_in_range_it_is_close_to_the_mean() -> None:
    """No channel noise, every UAV hears every other: SenDFuse should reproduce the average."""
    options = dict(noise="none", comm_range=float("inf"), budget=6)
    sendfuse = uav_ipp.make_vec_env("env3", fusion="sendfuse", seed=3, **options)
    mean = uav_ipp.make_vec_env("env3", fusion="mean", seed=3, **options)
    rng = np.random.default_rng(3)
    obs_s, obs_m = sendfuse.reset(), mean.reset()
    diffs = []
    for _ in range(5):
        actions = _random_actions(obs_m, rng)
        obs_s, *_ = sendfuse.step(actions)
        obs_m, *_ = mean.step(actions)
        raw = slice(0, layout.FUSED)
        np.testing.assert_array_equal(obs_s[layout.KEY_LOCAL][:, raw], obs_m[layout.KEY_LOCAL][:, raw])
        diffs.append(np.abs(obs_s[layout.KEY_LOCAL][:, layout.FUSED] - obs_m[layout.KEY_LOCAL][:, layout.FUSED]))
    diffs = np.stack(diffs)
    # shipped weights (v2, residual): mean ~0.0006, max ~0.008 (lattice values live in [0, 1])
    assert diffs.mean() < 0.01, diffs.mean()
    assert diffs.max() < 0.08, diffs.max()


def test_missing_weights_give_a_clear_error(tmp_path) -> None:
    missing = tmp_path / "absent.safetensors"
    with pytest.raises(SenDFuseWeightsError, match=str(missing)):
        uav_ipp.make_vec_env("env3", fusion="sendfuse", fusion_kwargs={"weights": missing})


def test_corrupt_weights_give_a_clear_error(tmp_path) -> None:
    corrupt = tmp_path / "corrupt.safetensors"
    corrupt.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00not a header at all")
    with pytest.raises(ValueError, match=str(corrupt)):
        uav_ipp.make_vec_env("env3", fusion="sendfuse", fusion_kwargs={"weights": corrupt})


def test_one_batched_network_call_per_step() -> None:
    net = CountingNet()
    n_envs, budget = 3, 4
    venv = uav_ipp.make_vec_env(
        "env3", n_envs=n_envs, fusion="sendfuse", seed=0, budget=budget, fusion_kwargs={"network": net}
    )
    rng = np.random.default_rng(0)
    obs = venv.reset()
    assert net.calls == [n_envs * 4]  # every agent of every copy in one call
    for step in range(1, budget + 1):
        net.calls.clear()
        obs, _, dones, _ = venv.step(_random_actions(obs, rng))
        if step < budget:
            assert net.calls == [n_envs * 4]
        else:  # the copies finish together: their terminal observations join the same call
            assert dones.all() and net.calls == [2 * n_envs * 4]


def test_large_batches_are_fused_in_chunks_with_the_same_result() -> None:
    """More agents than ``FUSE_CHUNK`` are fused in several calls (bounded memory), each row as
    if fused alone."""
    from sb3_coma.app.export import fusion_wrapper
    from sb3_coma.sendfuse.wrapper import FUSE_CHUNK

    net = CountingNet()
    venv = uav_ipp.make_vec_env("env3", n_envs=1, fusion="sendfuse", seed=0, fusion_kwargs={"network": net})
    wrapper = fusion_wrapper(venv)
    rng = np.random.default_rng(1)
    rows = 2 * FUSE_CHUNK + 5
    received = rng.random((rows, 4, 44, 44), dtype=np.float32)
    valid = (rng.random((rows, 4)) > 0.3).astype(np.float32)
    net.calls.clear()
    fused = wrapper.fuse(received, valid)
    assert net.calls == [FUSE_CHUNK, FUSE_CHUNK, 5]
    alone = np.concatenate([wrapper.fuse(received[i : i + 1], valid[i : i + 1]) for i in (0, FUSE_CHUNK, rows - 1)])
    np.testing.assert_allclose(fused[[0, FUSE_CHUNK, rows - 1]], alone, rtol=0, atol=1e-5)
    venv.close()


def test_wrapper_uses_the_given_network_and_checks_its_grid() -> None:
    torch.manual_seed(0)
    with pytest.raises(ValueError, match="comm_grid"):
        uav_ipp.make_vec_env("env3", fusion="sendfuse", fusion_kwargs={"network": SenDFuseNet(grid_size=32)})


# ------------------------------------------------------------------ the entry point and the defaults
def test_sendfuse_is_found_through_its_entry_point() -> None:
    assert "sendfuse" in uav_ipp.available_fusions() and {"mean", "none"} <= set(uav_ipp.available_fusions())
    assert fusion.fusion_factory("sendfuse") is SenDFuseFusionWrapper
    assert fusion.fusion_factory("mean") is fusion.MeanFusionWrapper


def test_default_vec_env_is_env3_with_sendfuse() -> None:
    venv = uav_ipp.make_vec_env(budget=2)
    assert uav_ipp.DEFAULT_MAP == "env3" and venv.get_attr("config", indices=[0])[0].map_name == "env3"
    assert isinstance(venv.venv.venv, SenDFuseFusionWrapper) and uav_ipp.DEFAULT_FUSION == "sendfuse"
    venv.close()


def test_unknown_and_broken_fusions_name_the_choices(monkeypatch) -> None:
    with pytest.raises(ValueError, match=r"unknown fusion 'median'; choose one of \['mean', 'none', 'sendfuse'\]"):
        uav_ipp.make_vec_env("env3", fusion="median")
    broken = {"ghost": fusion.metadata.EntryPoint("ghost", "no_such_module:Wrapper", fusion.ENTRY_POINT_GROUP)}
    monkeypatch.setattr(fusion, "_installed_fusions", lambda: broken)
    assert uav_ipp.available_fusions() == ["ghost", "mean", "none"]
    with pytest.raises(ConfigError, match=r"fusion 'ghost' \(no_such_module:Wrapper\) cannot be loaded"):
        uav_ipp.make_vec_env("env3", fusion="ghost")
    monkeypatch.setattr(fusion, "_installed_fusions", dict)
    with pytest.raises(ValueError, match=r"no package provides entry points 'uav_ipp\.fusion'"):
        uav_ipp.make_vec_env("env3", fusion="sendfuse")
