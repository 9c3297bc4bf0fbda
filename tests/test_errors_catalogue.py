"""The bad-input catalogue of ``docs/errors.md``: every entry is one parametrised case here.

Each case feeds one bad input to a public entry point (env options, map files and rules, fusion
options, actions passed to ``step``, COMA's constructor, YAML configs, model and weight files,
``sb3_coma.evaluate``, the ``sb3-coma`` CLI) and asserts

* the exact error type (never an ``IndexError``/``KeyError``/``AttributeError`` from deep inside),
* that the message names the bad value, and, where the entry says so, what is allowed;
* for CLI entries: ``sb3_coma.cli.main`` returns 2 and prints exactly one stderr line,
  ``sb3-coma <command>: error: ...``, and no traceback.

Property tests at the end feed arbitrary values to the same surfaces and check that only the
documented, user-facing error types come out.

``python tests/test_errors_catalogue.py`` prints the Markdown table of ``docs/errors.md`` from
the real messages (temporary paths shown as ``<tmp>``).
"""

from __future__ import annotations

import contextlib
import errno
import functools
import io
import json
import os
import shutil
import sys
import tempfile
import warnings
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import uav_ipp
from uav_ipp import ConfigError, MapError

DOC = Path(__file__).resolve().parent.parent / "docs" / "errors.md"
ENV_ID = "UavIpp-Env1-v0"
TINY = {
    ENV_ID: {
        "n_timesteps": 8,
        "n_envs": 1,
        "policy": "UavCnnPolicy",
        "policy_kwargs": {"features_extractor_kwargs": {"features_dim": 16}},
        "batch_size": 8,
        "env_kwargs": {"fusion": "mean", "n_uavs": 2, "budget": 4, "noise": "moderate"},
    },
    "variants": {"loud": {"env_kwargs": {"noise": "loud"}}},
}


# =============================================================================== prepared files
class Files:
    """Bad (and a few good) files in one temporary folder, made on first use."""

    def __init__(self, root: Path) -> None:
        self.root = root
        for folder in ("maps", "models", "weights"):
            (root / folder).mkdir(parents=True, exist_ok=True)

    def folder(self, name: str) -> Path:
        """An empty folder."""
        p = self.path(name)
        p.mkdir(parents=True, exist_ok=True)
        return p

    def path(self, name: str) -> Path:
        return self.root / name

    def text(self, name: str, content: str) -> Path:
        p = self.path(name)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(content)
        return p

    def config(self, name: str = "tiny.yml", data: dict | None = None) -> Path:
        return self.text(name, yaml.safe_dump(data or TINY))

    @functools.cached_property
    def venv(self):
        """The vec env COMA is built for (2 UAVs, mean fusion)."""
        return uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", n_uavs=2, budget=4)

    @functools.cached_property
    def raw_venv(self):
        return uav_ipp.make_vec_env("env1", n_envs=1, fusion="none", n_uavs=2, budget=4)

    @functools.cached_property
    def gainless_venv(self):
        return uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", n_uavs=2, budget=4, action_gain=False)

    @functools.cached_property
    def env(self):
        """A PettingZoo env for the action cases (reset before every use)."""
        return uav_ipp.make_env("env1", n_uavs=2, budget=4)

    def reset_env(self):
        self.env.reset(seed=0)
        return self.env

    @functools.cached_property
    def coma_zip(self) -> Path:
        """A valid COMA checkpoint trained for 2 UAVs (no training: just the saved networks)."""
        from sb3_coma import COMA
        from sb3_coma.common.checkpoints import atomic_save

        model = COMA(
            "UavCnnPolicy",
            self.venv,
            batch_size=8,
            seed=0,
            policy_kwargs={"features_extractor_kwargs": {"features_dim": 16}},
        )
        return atomic_save(model, self.path("models/coma_2uavs.zip"))

    @functools.cached_property
    def trained_zip(self) -> Path:
        """A COMA zip that records its training env as ``sb3-coma train`` does (2 UAVs, mean fusion)."""
        from sb3_coma import COMA
        from sb3_coma.app.config import resolve_world
        from sb3_coma.app.training import record_env_options
        from sb3_coma.common.checkpoints import atomic_save

        model = COMA(
            "UavCnnPolicy",
            self.venv,
            batch_size=8,
            seed=0,
            policy_kwargs={"features_extractor_kwargs": {"features_dim": 16}},
        )
        record_env_options(model, resolve_world("UavIpp-Env1-v0", {"fusion": "mean", "n_uavs": 2, "budget": 4}, "test"))
        return atomic_save(model, self.path("models/coma_mean_2uavs.zip"))

    @functools.cached_property
    def bad_steps_zip(self) -> Path:
        """A COMA zip whose ``data`` says ``"num_timesteps": "abc"`` (hand-edited or foreign)."""
        p = self.path("models/badsteps.zip")
        with zipfile.ZipFile(self.coma_zip) as src, zipfile.ZipFile(p, "w") as out:
            for name in src.namelist():
                data = src.read(name)
                if name == "data":
                    data = json.dumps({**json.loads(data), "num_timesteps": "abc"}).encode()
                out.writestr(name, data)
        return p

    @functools.cached_property
    def a_file(self) -> Path:
        """A regular file where a folder is expected."""
        return self.text("a_file", "not a folder")

    @functools.cached_property
    def truncated_zip(self) -> Path:
        data = self.coma_zip.read_bytes()
        p = self.path("models/truncated.zip")
        p.write_bytes(data[: len(data) // 2])
        return p

    @functools.cached_property
    def crc_zip(self) -> Path:
        """A complete zip whose policy.pth bytes were damaged (fails the member's CRC check)."""
        p = self.path("models/bitrot.zip")
        with zipfile.ZipFile(self.coma_zip) as archive:
            info = archive.getinfo("policy.pth")
        data = bytearray(self.coma_zip.read_bytes())
        start = info.header_offset + 30 + len(info.filename) + len(info.extra)
        data[start + info.compress_size // 2] ^= 0xFF
        p.write_bytes(bytes(data))
        return p

    @functools.cached_property
    def badpth_zip(self) -> Path:
        """A well-formed zip (CRCs fine) whose policy.pth is not a PyTorch file."""
        p = self.path("models/badpth.zip")
        with zipfile.ZipFile(self.coma_zip) as src, zipfile.ZipFile(p, "w") as out:
            for name in src.namelist():
                out.writestr(name, b"not a torch file" if name == "policy.pth" else src.read(name))
        return p

    @functools.cached_property
    def ppo_zip(self) -> Path:
        from stable_baselines3 import PPO

        p = self.path("models/ppo.zip")
        PPO("MlpPolicy", "CartPole-v1", n_steps=16, batch_size=16, device="cpu").save(p)
        return p

    @functools.cached_property
    def junk_zip(self) -> Path:
        return self.text("models/junk.zip", "this is not a zip")

    # ---- SenDFuse weight files (a small network: only the file format matters here)
    def _net(self, grid: int = 44):
        from sb3_coma.sendfuse import SenDFuseConfig, SenDFuseNet

        return SenDFuseNet.from_config(SenDFuseConfig(grid_size=grid, channels=(4, 4, 4)))

    @functools.cached_property
    def weights(self) -> Path:
        from sb3_coma.sendfuse import save_weights

        return save_weights(self._net(), self.path("weights/good.safetensors"))

    @functools.cached_property
    def weights_truncated(self) -> Path:
        data = self.weights.read_bytes()
        p = self.path("weights/truncated.safetensors")
        p.write_bytes(data[: len(data) // 2])
        return p

    @functools.cached_property
    def weights_bitflip(self) -> Path:
        data = bytearray(self.weights.read_bytes())
        data[-5] ^= 0xFF  # inside the last tensor's bytes; the header still parses
        p = self.path("weights/bitflip.safetensors")
        p.write_bytes(bytes(data))
        return p

    @functools.cached_property
    def weights_foreign(self) -> Path:
        import torch
        from safetensors.torch import save_file

        p = self.path("weights/foreign.safetensors")
        save_file({"x": torch.zeros(2)}, str(p), metadata={"format": "pt"})
        return p

    @functools.cached_property
    def weights_nan(self) -> Path:
        import torch

        from sb3_coma.sendfuse import save_weights

        net = self._net()
        with torch.no_grad():
            next(net.parameters()).fill_(float("nan"))
        return save_weights(net, self.path("weights/nan.safetensors"))

    @functools.cached_property
    def weights_r40(self) -> Path:
        from sb3_coma.sendfuse import save_weights

        return save_weights(self._net(40), self.path("weights/r40.safetensors"))

    # ---- images
    @functools.cached_property
    def not_an_image(self) -> Path:
        return self.text("maps/field.png", "hello, I am text")

    @functools.cached_property
    def blank_image(self) -> Path:
        import cv2

        p = self.path("maps/blank.png")
        cv2.imwrite(str(p), np.full((64, 64), 255, np.uint8))
        return p

    def close(self) -> None:
        for name in ("venv", "raw_venv", "gainless_venv"):
            if name in self.__dict__:
                self.__dict__[name].close()


# =============================================================================== the catalogue
@dataclass(frozen=True)
class Case:
    """One bad input. ``run(files)`` raises ``error``; the message contains every ``names`` entry
    (the bad value) and ``allowed`` (what is allowed), when given."""

    id: str
    surface: str
    bad_input: str
    run: Callable[[Files], Any]
    error: type[BaseException]
    names: tuple[str, ...]
    allowed: str | None = None


@dataclass(frozen=True)
class CliCase:
    """``sb3-coma ARGV`` exits with ``rc`` (2: a bad input; 1: the machine, e.g. a full disk) and
    one stderr line naming the bad value; ``within`` is the context it runs in (a machine without
    CUDA, a disk that fills up)."""

    id: str
    bad_input: str
    argv: Callable[[Files], list[str]]
    names: tuple[str, ...]
    allowed: str | None = None
    surface: str = field(default="CLI")
    rc: int = 2
    within: Callable[[], contextlib.AbstractContextManager[Any]] = contextlib.nullcontext


def _coma(files: Files, **kwargs):
    from sb3_coma import COMA

    kwargs.setdefault("batch_size", 8)
    policy = kwargs.pop("policy", "UavCnnPolicy")
    env = kwargs.pop("env", files.venv)
    return COMA(policy, env, **kwargs)


def _step(files: Files, actions: Any):
    return files.reset_env().step(actions)


def _step_after_end(files: Files):
    env = files.reset_env()
    while env.agents:
        env.step({a: 0 for a in env.agents})
    return env.step({"uav_0": 0, "uav_1": 0})


def _load_config(
    files: Files, overrides: dict | None = None, variant: str | None = None, env: str = "env1", path: Path | None = None
):
    from sb3_coma.app.training import load_config

    return load_config(env, path or files.config(), variant, overrides)


def _train(files: Files, **kwargs):
    from sb3_coma.app.training import train

    return train(progress_bar=False, verbose=0, handle_signals=False, runs_root=files.path("runs"), **kwargs)


def _evaluate(method: Any, **kwargs):
    from sb3_coma import evaluate

    kwargs.setdefault("env", "env1")
    kwargs.setdefault("n_trials", 1)
    return evaluate(method, **kwargs)


def _load_weights(path: Path, **kwargs):
    from sb3_coma.sendfuse import load_weights

    return load_weights(path, **kwargs)


def _with_extra_member(f: Files) -> Path:
    """A valid COMA zip with a member SB3 never writes (a payload riding along)."""
    import shutil
    import zipfile

    carrier = f.path("carrier.zip")
    shutil.copy(f.coma_zip, carrier)
    with zipfile.ZipFile(carrier, "a") as archive:
        archive.writestr("payload.py", "print('hello')")
    return carrier


def _nan_zip(f: Files) -> Path:
    """A COMA zip whose actor holds a NaN (a diverged run)."""
    import torch

    from sb3_coma import COMA

    model = COMA.load(f.coma_zip, device="cpu")
    with torch.no_grad():
        model.policy.actor.head.weight[0, 0] = float("nan")
    model.save(f.path("diverged.zip"))
    return f.path("diverged.zip")


def _load_model(path: Path):
    from sb3_coma import COMA

    return COMA.load(path, device="cpu")


def _foreign_out(f: Files) -> list[str]:
    """``evaluate --out`` into a folder of the user's own files."""
    out = f.folder("my_results")
    (out / "thesis.xlsx").write_text("the user's")
    return ["evaluate", "--methods", "random", "--env", "env1", "--trials", "1", "--no-plots", "--out", str(out)]


def _validate(path: Path):
    from sb3_coma.common.checkpoints import validate_checkpoint

    return validate_checkpoint(path)


def _load_checkpoint(path: Path, files: Files):
    from sb3_coma.app.runs import load_checkpoint

    return load_checkpoint(path, env=files.venv, device="cpu")


def _nodata_tiff(files: Files) -> Path:
    """A float32 TIFF of temperatures, 100 x 100, whose left quarter holds -9999 (GIS's NoData fill)."""
    from PIL import Image

    values = np.linspace(280.0, 300.0, 10_000, dtype=np.float32).reshape(100, 100)
    values[:, :25] = -9999.0
    path = files.path("maps/dem.tif")
    Image.fromarray(values).save(path)
    return path


def _unguarded_script(files: Files) -> None:
    """Run, as this process's main script, one that starts env workers at its top level (no guard)."""
    import runpy

    script = files.text(
        "unguarded/script.py",
        'import uav_ipp\nuav_ipp.make_vec_env("env1", n_envs=2, n_uavs=2, budget=4, workers=2)\n',
    )
    runpy.run_path(str(script), run_name="__main__")


def _no_gpu() -> contextlib.AbstractContextManager[Any]:
    """A machine without CUDA or MPS, whatever this one has (the cases must not depend on it)."""
    import torch

    stack = contextlib.ExitStack()
    stack.enter_context(mock.patch.object(torch.cuda, "is_available", return_value=False))
    stack.enter_context(mock.patch.object(torch.backends.mps, "is_available", return_value=False))
    return stack


def _disk_full_after(saves: int) -> contextlib.AbstractContextManager[Any]:
    """A disk that fills up after ``saves`` model saves: the next ``COMA.save`` writes a few bytes
    into the (temporary) file and fails with ``ENOSPC``, as ``write`` does on a full disk."""
    from sb3_coma import COMA

    original = COMA.save
    done = [0]

    def save(self, path, *args, **kwargs):
        done[0] += 1
        if done[0] > saves:
            path.write(b"PK\x03\x04 cut")
            raise OSError(errno.ENOSPC, "No space left on device")
        return original(self, path, *args, **kwargs)

    return mock.patch.object(COMA, "save", save)


def _as_error(run: Callable[[], Any]) -> Any:
    """Run with ``UserWarning`` raised as an exception: a warning case of the catalogue."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        return run()


def _train_without_gpu(files: Files, device: str):
    with _no_gpu():
        return _train(files, env="env1", config=files.config(), device=device)


def _coma_without_gpu(files: Files, device: str):
    with _no_gpu():
        return _coma(files, device=device)


def _save_on_full_disk(files: Files):
    """``atomic_save`` over an existing model while the disk is full."""
    from sb3_coma.common.checkpoints import atomic_save

    model = _coma(files, policy_kwargs={"features_extractor_kwargs": {"features_dim": 16}})
    previous = files.path("models/previous.zip")
    shutil.copyfile(files.coma_zip, previous)
    with _disk_full_after(0):
        return atomic_save(model, previous)


def _task(env_id: str):
    from sb3_coma.app.marl_tasks import resolve_task

    return resolve_task(env_id)


def _zoo_args(argv: list[str]):
    from sb3_coma.app import zoo

    return zoo.train_parser().parse_args(argv)


#: A file name whose bytes are not valid UTF-8, as Python hands it over from the command line.
BAD_NAME = os.fsdecode(b"bad\xff")


def _replaced_shipped_weights(files: Files):
    """``make_vec_env(fusion="sendfuse")`` while the package's weights folder (a copy) holds
    another network under the shipped file name."""
    from sb3_coma.sendfuse import save_weights
    from sb3_coma.sendfuse import weights as weights_mod

    folder = files.folder("pkg_weights").resolve()
    save_weights(files._net(), folder / "sendfuse_r44.safetensors")
    with mock.patch.object(weights_mod, "shipped_weights_dir", lambda: folder):
        return uav_ipp.make_vec_env("env1", fusion="sendfuse", n_uavs=2, budget=2)


def _replaced_shipped_model(files: Files):
    """``evaluate(<package>/coma_env1.zip)`` by its path, while that file (in a copy of the package's
    folder) holds another model."""
    from sb3_coma.app import pretrained

    folder = files.folder("pkg_models").resolve()
    shutil.copyfile(pretrained.pretrained_dir() / pretrained.MANIFEST, folder / pretrained.MANIFEST)
    shutil.copyfile(pretrained.pretrained_dir() / "coma_env2.zip", folder / "coma_env1.zip")
    with mock.patch.object(pretrained, "pretrained_dir", lambda: folder):
        return _evaluate(str(folder / "coma_env1.zip"), n_uavs=2, budget=2)


def _errors():
    from sb3_coma.app.training import TrainingError
    from sb3_coma.common.checkpoints import CheckpointError, DiskFullError
    from sb3_coma.sendfuse import SenDFuseWeightsError

    return CheckpointError, DiskFullError, SenDFuseWeightsError, TrainingError


CheckpointError, DiskFullError, SenDFuseWeightsError, TrainingError = _errors()
from sb3_coma.coma.validation import BatchLargerThanRollout  # noqa: E402  (after the world's imports, as _errors)


def _v3_types():
    from sb3_coma.app.evaluation import WorldMismatchWarning
    from sb3_coma.app.pretrained import PretrainedError

    return PretrainedError, WorldMismatchWarning


PretrainedError, WorldMismatchWarning = _v3_types()
E = "env option"
M = "map"
F = "fusion"
A = "action (step)"
C = "COMA()"
Y = "YAML config and train()"
MF = "model file"
W = "SenDFuse weights"
EV = "evaluate()"
Z = "rl-zoo3 entry (python -m sb3_coma.zoo)"

#: A quick evaluation (2 UAVs, 2 decisions, one mission): a case fails fast even if unchecked.
_QUICK_EVALUATE = ["evaluate", "--methods", "random", "--trials", "1", "--uavs", "2", "--budget", "2", "--no-plots"]

CASES: list[Case | CliCase] = [
    # ------------------------------------------------------------------ env options
    Case(
        "env-n_uavs-zero",
        E,
        'make_env("env1", n_uavs=0)',
        lambda f: uav_ipp.make_env("env1", n_uavs=0),
        ConfigError,
        ("n_uavs=0",),
        "an integer >= 1",
    ),
    Case(
        "env-n_uavs-bool",
        E,
        'make_env("env1", n_uavs=True)',
        lambda f: uav_ipp.make_env("env1", n_uavs=True),
        ConfigError,
        ("n_uavs=True",),
        "an integer >= 1",
    ),
    Case(
        "env-n_uavs-too-many",
        E,
        'make_env("env1", n_uavs=200)',
        lambda f: uav_ipp.make_env("env1", n_uavs=200),
        ConfigError,
        ("n_uavs=200",),
        "at most 121",
    ),
    Case(
        "env-mission-from-seed-paper",
        E,
        'make_env("env1", mission_from_seed=True)',
        lambda f: uav_ipp.make_env("env1", mission_from_seed=True),
        ConfigError,
        ("mission_from_seed=True",),
        "False with split='paper'",
    ),
    Case(
        "env-mission-from-seed-text",
        E,
        'make_env("env3", split="train", mission_from_seed="yes")',
        lambda f: uav_ipp.make_env("env3", split="train", mission_from_seed="yes"),
        ConfigError,
        ("mission_from_seed='yes'",),
        "True or False",
    ),
    Case(
        "env-budget-zero",
        E,
        'make_env("env1", budget=0)',
        lambda f: uav_ipp.make_env("env1", budget=0),
        ConfigError,
        ("budget=0",),
        "an integer >= 1",
    ),
    Case(
        "env-noise-unknown",
        E,
        'make_env("env1", noise="quiet")',
        lambda f: uav_ipp.make_env("env1", noise="quiet"),
        ConfigError,
        ("noise='quiet'",),
        "['loud', 'moderate', 'none']",
    ),
    Case(
        "env-noise-list",
        E,
        'make_env("env1", noise=["loud"])',
        lambda f: uav_ipp.make_env("env1", noise=["loud"]),
        ConfigError,
        ("noise=['loud']",),
        "['loud', 'moderate', 'none']",
    ),
    Case(
        "env-unknown-option",
        E,
        'make_env("env1", n_uav=3)',
        lambda f: uav_ipp.make_env("env1", n_uav=3),
        ConfigError,
        ("['n_uav']",),
        "allowed options",
    ),
    Case(
        "env-reward-unknown",
        E,
        'make_env("env1", reward="money")',
        lambda f: uav_ipp.make_env("env1", reward="money"),
        ConfigError,
        ("reward='money'",),
        "'entropy'",
    ),
    Case(
        "env-action_gain-not-bool",
        E,
        'make_env("env1", action_gain="yes")',
        lambda f: uav_ipp.make_env("env1", action_gain="yes"),
        ConfigError,
        ("action_gain='yes'",),
        "True",
    ),
    Case(
        "env-observation-unknown",
        E,
        'make_env("env1", observation="v4")',
        lambda f: uav_ipp.make_env("env1", observation="v4"),
        ConfigError,
        ("observation='v4'",),
        "'v2', 'v3'",
    ),
    Case(
        "env-comm_range-negative",
        E,
        'make_env("env1", comm_range=-1)',
        lambda f: uav_ipp.make_env("env1", comm_range=-1),
        ConfigError,
        ("comm_range=-1",),
        "a distance >= 0",
    ),
    Case(
        "env-comm_grid-not-multiple-of-4",
        E,
        'make_env("env1", comm_grid=45)',
        lambda f: uav_ipp.make_env("env1", comm_grid=45),
        ConfigError,
        ("comm_grid=45",),
        "a multiple of 4",
    ),
    Case(
        "env-start-unknown",
        E,
        'make_env("env1", start="corner")',
        lambda f: uav_ipp.make_env("env1", start="corner"),
        ConfigError,
        ("start='corner'",),
        "'fixed' or 'random'",
    ),
    Case(
        "env-start_positions-off-lattice",
        E,
        'make_env("env1", n_uavs=1, start_positions=[(12, 10, 15)])',
        lambda f: uav_ipp.make_env("env1", n_uavs=1, start_positions=[(12, 10, 15)]),
        ConfigError,
        ("(12.0, 10.0, 15.0)",),
        "multiples of 5 m",
    ),
    Case(
        "env-start_positions-shared-column",
        E,
        'make_env("env1", n_uavs=2, start_positions=[(10, 10, 15), (10, 10, 5)])',
        lambda f: uav_ipp.make_env("env1", n_uavs=2, start_positions=[(10, 10, 15), (10, 10, 5)]),
        ConfigError,
        ("(10.0, 10.0, 5.0)",),
        "distinct (x, y) columns",
    ),
    Case(
        "env-altitudes-unsorted",
        E,
        'make_env("env1", altitudes=[15, 10, 5])',
        lambda f: uav_ipp.make_env("env1", altitudes=[15, 10, 5]),
        ConfigError,
        ("altitudes=(15.0, 10.0, 5.0)",),
        "strictly increasing",
    ),
    Case(
        "env-altitudes-not-a-list",
        E,
        'make_env("env1", altitudes=5)',
        lambda f: uav_ipp.make_env("env1", altitudes=5),
        ConfigError,
        ("altitudes=5",),
        "a non-empty list of positive altitudes",
    ),
    Case(
        "env-flip_probability-too-high",
        E,
        'make_env("env1", flip_probability={5: 0.1, 10: 0.2, 15: 0.7})',
        lambda f: uav_ipp.make_env("env1", flip_probability={5: 0.1, 10: 0.2, 15: 0.7}),
        ConfigError,
        ("altitude 15.0 has 0.7",),
        "strictly between 0 and 0.5",
    ),
    Case(
        "env-fov_deg-text",
        E,
        'make_env("env1", fov_deg="wide")',
        lambda f: uav_ipp.make_env("env1", fov_deg="wide"),
        ConfigError,
        ("fov_deg='wide'",),
        "(0, 180) degrees",
    ),
    Case(
        "env-drop_probability-above-1",
        E,
        'make_env("env1", drop_probability=2)',
        lambda f: uav_ipp.make_env("env1", drop_probability=2),
        ConfigError,
        ("drop_probability=2",),
        "in [0, 1]",
    ),
    Case(
        "env-render_mode-human",
        E,
        'make_env("env1", render_mode="human")',
        lambda f: uav_ipp.make_env("env1", render_mode="human"),
        ConfigError,
        ("render_mode='human'",),
        "'rgb_array' or 'ansi'",
    ),
    Case(
        "vec-n_envs-zero",
        E,
        'make_vec_env("env1", n_envs=0)',
        lambda f: uav_ipp.make_vec_env("env1", n_envs=0),
        ConfigError,
        ("n_envs=0",),
        "an integer >= 1",
    ),
    Case(
        "vec-seed-text",
        E,
        'make_vec_env("env1", seed="a")',
        lambda f: uav_ipp.make_vec_env("env1", seed="a"),
        ConfigError,
        ("seed='a'",),
        "an integer or None",
    ),
    # ------------------------------------------------------------------ maps
    Case(
        "map-unknown-name",
        M,
        'make_env("env9")',
        lambda f: uav_ipp.make_env("env9"),
        MapError,
        ("'env9'",),
        "['env1', 'env2', 'env3']",
    ),
    Case(
        "map-file-as-name",
        M,
        'make_env("field.png")',
        lambda f: uav_ipp.make_env("field.png"),
        MapError,
        ("'field.png'",),
        "map_path='field.png'",
    ),
    Case(
        "map-path-missing",
        M,
        'make_env("mine", map_path="<tmp>/maps/missing.png")',
        lambda f: uav_ipp.make_env("mine", map_path=f.path("maps/missing.png")),
        MapError,
        ("missing.png",),
        "does not exist",
    ),
    Case(
        "map-path-not-an-image",
        M,
        'make_env("mine", map_path="<tmp>/maps/field.png")  # a text file',
        lambda f: uav_ipp.make_env("mine", map_path=f.not_an_image),
        MapError,
        ("field.png",),
        "PNG, JPEG, TIFF",
    ),
    Case(
        "map-path-blank-image",
        M,
        'make_env(map_path="<tmp>/maps/blank.png")  # all white',
        lambda f: uav_ipp.make_env(map_path=f.blank_image),
        MapError,
        ("'blank'", "'threshold'"),
        "choose another rule",
    ),
    Case(
        "map-path-nodata-fill",
        M,
        'make_env("mine", map_path="<tmp>/maps/dem.tif", valuable="coldest:0.3")  # a warning: float32 TIFF, '
        "left quarter -9999",
        lambda f: _as_error(lambda: uav_ipp.make_env("mine", map_path=_nodata_tiff(f), valuable="coldest:0.3")),
        UserWarning,
        ("NoData fill -9999", "2,500 of 10,000 pixels"),
        "never valuable",
    ),
    Case(
        "map-rule-unknown",
        M,
        'make_env("env2", valuable="bogus")',
        lambda f: uav_ipp.make_env("env2", valuable="bogus"),
        MapError,
        ("'bogus'",),
        "allowed rules",
    ),
    Case(
        "map-rule-missing-fraction",
        M,
        'make_env("env2", valuable="hottest")',
        lambda f: uav_ipp.make_env("env2", valuable="hottest"),
        MapError,
        ("'hottest'",),
        "'hottest:0.3'",
    ),
    Case(
        "map-rule-fraction-out-of-range",
        M,
        'make_env("env2", valuable="hottest:1.5")',
        lambda f: uav_ipp.make_env("env2", valuable="hottest:1.5"),
        MapError,
        ("'hottest:1.5'",),
        "strictly between 0 and 1",
    ),
    Case(
        "map-rule-not-a-number",
        M,
        'make_env("env2", valuable="threshold:x")',
        lambda f: uav_ipp.make_env("env2", valuable="threshold:x"),
        MapError,
        ("'threshold:x'", "'x'"),
        "is not a number",
    ),
    Case(
        "map-rule-ndvi-without-nir",
        M,
        'make_env("env2", valuable="ndvi:0.5")',
        lambda f: uav_ipp.make_env("env2", valuable="ndvi:0.5"),
        MapError,
        ("'ndvi:0.5'", "'env2'"),
        "only env3 ships",
    ),
    Case(
        "map-rule-selects-nothing",
        M,
        'make_env("env2", valuable="threshold:1.0")',
        lambda f: uav_ipp.make_env("env2", valuable="threshold:1.0"),
        MapError,
        ("'threshold:1'",),
        "choose another rule or threshold",
    ),
    Case(
        "map-grid-too-large",
        M,
        'make_env("env1", grid=100000)',
        lambda f: uav_ipp.make_env("env1", grid=100000),
        MapError,
        ("grid=100000",),
        "[11, 8192]",
    ),
    # ------------------------------------------------------------------ fusion
    Case(
        "fusion-unknown",
        F,
        'make_vec_env("env1", fusion="median")',
        lambda f: uav_ipp.make_vec_env("env1", fusion="median"),
        ValueError,
        ("'median'",),
        "'mean'",
    ),
    Case(
        "fusion-kwargs-unknown",
        F,
        'make_vec_env("env1", fusion="mean", fusion_kwargs={"alpha": 0.5})',
        lambda f: uav_ipp.make_vec_env("env1", fusion="mean", fusion_kwargs={"alpha": 0.5}),
        ConfigError,
        ("['alpha']",),
        "it takes no options",
    ),
    Case(
        "fusion-sendfuse-alpha-out-of-range",
        F,
        'make_vec_env("env1", fusion="sendfuse", fusion_kwargs={"weights": W, "alpha": 5})',
        lambda f: uav_ipp.make_vec_env(
            "env1", n_uavs=2, fusion="sendfuse", fusion_kwargs={"weights": f.weights, "alpha": 5}
        ),
        ConfigError,
        ("alpha=5",),
        "a number in [0, 1]",
    ),
    Case(
        "fusion-sendfuse-weights-missing",
        F,
        'make_vec_env("env1", fusion="sendfuse", fusion_kwargs={"weights": "<tmp>/none.safetensors"})',
        lambda f: uav_ipp.make_vec_env(
            "env1", n_uavs=2, fusion="sendfuse", fusion_kwargs={"weights": f.path("none.safetensors")}
        ),
        SenDFuseWeightsError,
        ("none.safetensors",),
        "sb3-coma pretrain-sendfuse",
    ),
    Case(
        "fusion-sendfuse-grid-mismatch",
        F,
        'make_vec_env("env1", fusion="sendfuse", fusion_kwargs={"weights": <R=40 file>})  # env comm_grid 44',
        lambda f: uav_ipp.make_vec_env("env1", n_uavs=2, fusion="sendfuse", fusion_kwargs={"weights": f.weights_r40}),
        ValueError,
        ("40 x 40", "comm_grid=44"),
    ),
    # ------------------------------------------------------------------ actions passed to step
    Case(
        "step-not-a-dict",
        A,
        "env.step([0, 1])",
        lambda f: _step(f, [0, 1]),
        TypeError,
        ("list",),
        "a dict agent -> action",
    ),
    Case(
        "step-action-out-of-range",
        A,
        'env.step({"uav_0": 6, "uav_1": 0})',
        lambda f: _step(f, {"uav_0": 6, "uav_1": 0}),
        ValueError,
        ("uav_0", "got 6"),
        "an integer in 0..5",
    ),
    Case(
        "step-action-text",
        A,
        'env.step({"uav_0": "up", "uav_1": 0})',
        lambda f: _step(f, {"uav_0": "up", "uav_1": 0}),
        ValueError,
        ("uav_0", "'up'"),
        "an integer in 0..5",
    ),
    Case(
        "step-action-infinite",
        A,
        'env.step({"uav_0": float("inf"), "uav_1": 0})',
        lambda f: _step(f, {"uav_0": float("inf"), "uav_1": 0}),
        ValueError,
        ("uav_0", "inf"),
        "an integer in 0..5",
    ),
    Case(
        "step-action-fraction",
        A,
        'env.step({"uav_0": 1.5, "uav_1": 0})',
        lambda f: _step(f, {"uav_0": 1.5, "uav_1": 0}),
        ValueError,
        ("uav_0", "1.5"),
        "an integer in 0..5",
    ),
    Case(
        "step-agent-missing",
        A,
        'env.step({"uav_0": 0})',
        lambda f: _step(f, {"uav_0": 0}),
        ValueError,
        ("['uav_1']",),
        "every live agent must act",
    ),
    Case(
        "step-agent-unknown",
        A,
        'env.step({"uav_0": 0, "uav_1": 0, "uav_7": 1})',
        lambda f: _step(f, {"uav_0": 0, "uav_1": 0, "uav_7": 1}),
        ValueError,
        ("['uav_7']",),
        "agents are ['uav_0', 'uav_1']",
    ),
    Case(
        "step-after-mission-end",
        A,
        "env.step(...) after the last step",
        _step_after_end,
        RuntimeError,
        ("finished mission",),
        "call reset() first",
    ),
    # ------------------------------------------------------------------ COMA constructor
    Case(
        "coma-policy-unknown",
        C,
        'COMA("NoSuchPolicy", venv)',
        lambda f: _coma(f, policy="NoSuchPolicy"),
        ValueError,
        ("'NoSuchPolicy'",),
        "['CBAMPolicy', 'CnnPolicy', 'MlpPolicy', 'MultiInputPolicy', 'UavCOMAPolicy', 'UavCnnPolicy']",
    ),
    Case(
        "coma-generic-cnn-policy-on-dict",
        C,
        'COMA("CnnPolicy", venv)  # generic NatureCNN policy, the world has a Dict observation',
        lambda f: _coma(f, policy="CnnPolicy"),
        ValueError,
        ("'CnnPolicy'", "['action_gain', 'local']"),
        "'UavCnnPolicy'",
    ),
    Case(
        "coma-device-no-cuda",
        C,
        'COMA("UavCnnPolicy", venv, device="cuda")  # no GPU here',
        lambda f: _coma_without_gpu(f, "cuda"),
        ValueError,
        ("'cuda'",),
        "no CUDA device is available",
    ),
    Case(
        "coma-env-not-vec",
        C,
        'COMA("UavCnnPolicy", gymnasium.make("CartPole-v1"))',
        lambda f: _coma(f, env=__import__("gymnasium").make("CartPole-v1")),
        TypeError,
        ("TimeLimit",),
        "sb3_coma.make_marl_vec_env",
    ),
    Case(
        "coma-env-unfused",
        C,
        'COMA("UavCnnPolicy", make_vec_env(..., fusion="none"))',
        lambda f: _coma(f, env=f.raw_venv),
        ValueError,
        ("(7, 11, 11)",),
        "add a fusion wrapper",
    ),
    Case(
        "coma-gain_prior-negative",
        C,
        "COMA(..., policy_kwargs={'gain_prior': -1})",
        lambda f: _coma(f, policy_kwargs={"gain_prior": -1}),
        ValueError,
        ("gain_prior=-1",),
        ">= 0",
    ),
    Case(
        "coma-gain_prior-without-gain-key",
        C,
        'COMA(..., policy_kwargs={"gain_prior": 5}) on action_gain=False',
        lambda f: _coma(f, env=f.gainless_venv, policy_kwargs={"gain_prior": 5}),
        ValueError,
        ("gain_prior=5", "'action_gain'"),
        "action_gain=True",
    ),
    Case(
        "coma-gate_bias-not-a-number",
        C,
        "COMA('CBAMPolicy', ..., policy_kwargs={'features_extractor_kwargs': {'gate_bias': 'wide'}})",
        lambda f: _coma(f, policy="CBAMPolicy", policy_kwargs={"features_extractor_kwargs": {"gate_bias": "wide"}}),
        ValueError,
        ("gate_bias", "'wide'"),
        "a number",
    ),
    Case(
        "coma-correction_bound-zero",
        C,
        "COMA(..., policy_kwargs={'correction_bound': 0})",
        lambda f: _coma(f, policy_kwargs={"gain_prior": 5, "correction_bound": 0}),
        ValueError,
        ("correction_bound=0",),
        "a finite number > 0",
    ),
    Case(
        "coma-residual-not-a-bool",
        C,
        "COMA('CBAMPolicy', ..., policy_kwargs={'features_extractor_kwargs': {'residual': 'yes'}})",
        lambda f: _coma(f, policy="CBAMPolicy", policy_kwargs={"features_extractor_kwargs": {"residual": "yes"}}),
        ValueError,
        ("residual", "'yes'"),
        "true or false",
    ),
    Case(
        "coma-gain_prior-wrong-rows",
        C,
        "COMA(..., policy_kwargs={'gain_prior': [10, 0, 0]})",
        lambda f: _coma(f, policy_kwargs={"gain_prior": [10, 0, 0]}),
        ValueError,
        ("gain_prior=[10, 0, 0]", "got 3"),
        "one weight per 'action_gain' row",
    ),
    Case(
        "coma-learning_rate-zero",
        C,
        "COMA(..., learning_rate=0)",
        lambda f: _coma(f, learning_rate=0),
        ValueError,
        ("learning_rate", "got 0"),
        "must be a finite positive number",
    ),
    Case(
        "coma-gamma-above-1",
        C,
        "COMA(..., gamma=2.0)",
        lambda f: _coma(f, gamma=2.0),
        ValueError,
        ("gamma", "2.0"),
        "[0, 1]",
    ),
    Case(
        "coma-batch_size-zero",
        C,
        "COMA(..., batch_size=0)",
        lambda f: _coma(f, batch_size=0),
        ValueError,
        ("batch_size", "got 0"),
        ">= 1",
    ),
    Case(
        "coma-batch_size-float",
        C,
        "COMA(..., batch_size=2.5)",
        lambda f: _coma(f, batch_size=2.5),
        TypeError,
        ("batch_size", "2.5"),
        "an int",
    ),
    Case(
        "coma-n_steps-bool",
        C,
        "COMA(..., n_steps=True)",
        lambda f: _coma(f, n_steps=True),
        TypeError,
        ("n_steps", "True"),
        "an int",
    ),
    Case(
        "coma-batch-larger-than-rollout",
        C,
        "COMA(..., batch_size=64, n_steps=8)",
        lambda f: _coma(f, batch_size=64, n_steps=8),
        BatchLargerThanRollout,  # a ValueError; a hyperparameter search prunes such a trial
        ("batch_size=64", "n_steps=8"),
        "raise n_steps or lower batch_size",
    ),
    Case(
        "coma-exploration-eps-above-1",
        C,
        "COMA(..., exploration_initial_eps=1.5)",
        lambda f: _coma(f, exploration_initial_eps=1.5),
        ValueError,
        ("exploration_initial_eps", "1.5"),
        "[0, 1]",
    ),
    Case(
        "coma-learning_rate-inf",
        C,
        "COMA(..., learning_rate=float('inf'))",
        lambda f: _coma(f, learning_rate=float("inf")),
        ValueError,
        ("learning_rate", "got inf"),
        "must be a finite positive number",
    ),
    Case(
        "coma-advantage-unknown",
        C,
        "COMA(..., advantage='ppo')",
        lambda f: _coma(f, advantage="ppo"),
        ValueError,
        ("advantage", "'ppo'"),
        "must be one of",
    ),
    Case(
        "coma-v_return-uav-policy",
        C,
        "COMA('UavCnnPolicy', uav_env, advantage='v_return')",
        lambda f: _coma(f, advantage="v_return"),
        ValueError,
        ("advantage='v_return'", "UavCnnPolicy"),
        "needs a policy with a state value",
    ),
    Case(
        "coma-critic_time_feature-zero",
        C,
        "COMA(..., critic_time_feature=0)",
        lambda f: _coma(f, critic_time_feature=0),
        ValueError,
        ("critic_time_feature", "got 0"),
        "None or >= 1",
    ),
    Case(
        "coma-critic_time_feature-image-state",
        C,
        "COMA('UavCnnPolicy', uav_env, critic_time_feature=60)  # the world's state is map images",
        lambda f: _coma(f, critic_time_feature=60),
        ValueError,
        ("critic_time_feature", "Box("),
        "needs a flat state",
    ),
    Case(
        "coma-clip_range-zero",
        C,
        "COMA(..., clip_range=0)",
        lambda f: _coma(f, clip_range=0),
        ValueError,
        ("clip_range", "got 0"),
        "None, a positive number or a schedule of one",
    ),
    Case(
        "coma-max_grad_norm-zero",
        C,
        "COMA(..., max_grad_norm=0)",
        lambda f: _coma(f, max_grad_norm=0),
        ValueError,
        ("max_grad_norm", "got 0"),
        "must be positive",
    ),
    # ------------------------------------------------------------------ YAML configs (Python API)
    Case(
        "yaml-env-unknown",
        Y,
        'load_config("env9", "tiny.yml")',
        lambda f: _load_config(f, env="env9"),
        TrainingError,
        ("'env9'",),
        "use one of env1, env2, env3",
    ),
    Case(
        "yaml-file-missing",
        Y,
        'load_config("env1", "<tmp>/missing.yml")',
        lambda f: _load_config(f, path=f.path("missing.yml")),
        TrainingError,
        ("missing.yml",),
        "does not exist",
    ),
    Case(
        "yaml-syntax",
        Y,
        "batch_size: [8   (unclosed list)",
        lambda f: _load_config(f, path=f.text("broken.yml", f"{ENV_ID}:\n  n_timesteps: 8\n  batch_size: [8\n")),
        TrainingError,
        ("broken.yml", "line 4, column 1"),
        "not valid YAML",
    ),
    Case(
        "yaml-no-entry-for-env",
        Y,
        'load_config("env2", "tiny.yml")  # only an env1 entry',
        lambda f: _load_config(f, env="env2"),
        TrainingError,
        ("UavIpp-Env2-v0",),
        "it has: UavIpp-Env1-v0",
    ),
    Case(
        "yaml-variant-unknown",
        Y,
        'load_config("env1", "tiny.yml", variant="nope")',
        lambda f: _load_config(f, variant="nope"),
        TrainingError,
        ("'nope'",),
        "variants: loud",
    ),
    Case(
        "yaml-key-misspelt",
        Y,
        "batch_sise: 8",
        lambda f: _load_config(f, {"batch_sise": 8}),
        TrainingError,
        ("'batch_sise'",),
        "did you mean 'batch_size'",
    ),
    Case(
        "yaml-key-unsupported",
        Y,
        "normalize: true",
        lambda f: _load_config(f, {"normalize": True}),
        TrainingError,
        ("'normalize'",),
        "VecNormalize is not used",
    ),
    Case(
        "yaml-key-reserved",
        Y,
        "seed: 3",
        lambda f: _load_config(f, {"seed": 3}),
        TrainingError,
        ("'seed'",),
        "pass --seed",
    ),
    Case(
        "yaml-schedule-text",
        Y,
        "learning_rate: fast",
        lambda f: _load_config(f, {"learning_rate": "fast"}),
        TrainingError,
        ("'fast'",),
        "'lin_<initial value>'",
    ),
    Case(
        "yaml-n_timesteps-zero",
        Y,
        "n_timesteps: 0",
        lambda f: _load_config(f, {"n_timesteps": 0}),
        TrainingError,
        ("n_timesteps", "got 0"),
        "a positive integer",
    ),
    Case(
        "yaml-fusion-unknown",
        Y,
        "env_kwargs: {fusion: median}",
        lambda f: _load_config(f, {"env_kwargs.fusion": "median"}),
        TrainingError,
        ("'median'",),
        "('mean', 'sendfuse')",
    ),
    Case(
        "yaml-env_kwargs-bad-option",
        Y,
        "env_kwargs: {noise: quiet}",
        lambda f: _load_config(f, {"env_kwargs.noise": "quiet"}),
        TrainingError,
        ("noise='quiet'",),
        "['loud', 'moderate', 'none']",
    ),
    Case(
        "yaml-policy-not-importable",
        Y,
        "policy: mypkg.MyPolicy",
        lambda f: __import__("sb3_coma.app.config", fromlist=["coma_kwargs"]).coma_kwargs(
            _load_config(f, {"policy": "mypkg.MyPolicy"}).entry
        ),
        TrainingError,
        ("'mypkg.MyPolicy'",),
        "No module named 'mypkg'",
    ),
    Case(
        "yaml-policy_kwargs-syntax",
        Y,
        'policy_kwargs: "dict(net_arch=)"',
        lambda f: __import__("sb3_coma.app.config", fromlist=["resolve_policy_kwargs"]).resolve_policy_kwargs(
            "dict(net_arch=)"
        ),
        TrainingError,
        ("'dict(net_arch=)'",),
        "not a valid Python expression",
    ),
    Case(
        "yaml-callback-bad-arguments",
        Y,
        "callback: [{sb3_coma.common.callbacks.StopOnTargetCallback: {metric: speed}}]",
        lambda f: _train(
            f,
            env="env1",
            config=f.config(),
            overrides={"callback": [{"sb3_coma.common.callbacks.StopOnTargetCallback": {"metric": "speed"}}]},
        ),
        TrainingError,
        ("'speed'", "StopOnTargetCallback"),
        "('entropy', 'f1', 'reward')",
    ),
    Case(
        "yaml-features_dim-zero",
        Y,
        "policy_kwargs: {features_extractor_kwargs: {features_dim: 0}}",
        lambda f: _train(
            f,
            env="env1",
            config=f.config(),
            overrides={"policy_kwargs": {"features_extractor_kwargs": {"features_dim": 0}}},
        ),
        TrainingError,
        ("features_dim", "got 0"),
        "must be an integer >= 1",
    ),
    Case(
        "train-device-unknown",
        Y,
        'train(env="env1", config="tiny.yml", device="tpu")',
        lambda f: _train(f, env="env1", config=f.config(), device="tpu"),
        TrainingError,
        ("'tpu'",),
        "use auto, cpu, cuda",
    ),
    Case(
        "train-device-no-cuda",
        Y,
        'train(env="env1", config="tiny.yml", device="cuda")  # no GPU here',
        lambda f: _train_without_gpu(f, "cuda"),
        TrainingError,
        ("'cuda'",),
        "no CUDA device is available",
    ),
    Case(
        "train-device-no-mps",
        Y,
        'train(env="env1", config="tiny.yml", device="mps")  # not a Mac with an Apple GPU',
        lambda f: _train_without_gpu(f, "mps"),
        TrainingError,
        ("'mps'",),
        "no MPS (Apple GPU) device is available",
    ),
    Case(
        "train-run_dir-below-a-file",
        Y,
        'train(env="env1", config="tiny.yml", run_dir="<tmp>/a_file/sub")  # a_file is a file',
        lambda f: _train(f, env="env1", config=f.config(), run_dir=f.a_file / "sub"),
        TrainingError,
        ("a_file/sub", "a_file is a file"),
        "cannot be made",
    ),
    # ------------------------------------------------------------------ rl-zoo3 entry
    Case(
        "zoo-params-not-python",
        Z,
        "python -m sb3_coma.app.zoo train -params batch_size:abc",
        lambda f: _zoo_args(["-params", "batch_size:abc"]),
        TrainingError,
        ("batch_size", "'abc'"),
        "quote text",
    ),
    Case(
        "zoo-task-module-missing",
        Z,
        "python -m sb3_coma.zoo train --env no_such_pkg_xyz.envs:make_team",
        lambda f: _task("no_such_pkg_xyz.envs:make_team"),
        TrainingError,
        ("no_such_pkg_xyz.envs:make_team", "'no_such_pkg_xyz'"),
        "cannot import",
    ),
    Case(
        "zoo-task-not-callable",
        Z,
        "python -m sb3_coma.zoo train --env json:__name__",
        lambda f: _task("json:__name__"),
        TrainingError,
        ("json:__name__", "'__name__'"),
        "has no callable",
    ),
    Case(
        "zoo-task-env-kwargs-refused",
        Z,
        "python -m sb3_coma.zoo train --env simple_spread --env-kwargs n_agents:4",
        lambda f: _task("simple_spread").agents({"n_agents": 4}),
        TrainingError,
        ("simple_spread", "{'n_agents': 4}"),
        "unexpected keyword",
    ),
    # ------------------------------------------------------------------ model files
    Case(
        "model-missing",
        MF,
        'validate_checkpoint("<tmp>/models/none.zip")',
        lambda f: _validate(f.path("models/none.zip")),
        FileNotFoundError,
        ("none.zip",),
        "does not exist",
    ),
    Case(
        "model-not-a-zip",
        MF,
        'validate_checkpoint("<tmp>/models/junk.zip")  # a text file',
        lambda f: _validate(f.junk_zip),
        CheckpointError,
        ("junk.zip",),
        "not a zip archive",
    ),
    Case(
        "model-extra-member",
        MF,
        "validate_checkpoint(<a COMA zip with payload.py added>)",
        lambda f: _validate(_with_extra_member(f)),
        CheckpointError,
        ("carrier.zip", "payload.py"),
        "a COMA model zip never has",
    ),
    Case(
        "model-non-finite-weights",
        MF,
        "COMA.load(<a zip whose actor holds a NaN>)",
        lambda f: _load_model(_nan_zip(f)),
        ValueError,
        ("diverged.zip", "actor.head.weight"),
        "NaN or inf",
    ),
    Case(
        "coma-learn-timesteps-huge",
        C,
        "COMA(...).learn(1e100)",
        lambda f: _coma(f).learn(1e100),
        ValueError,
        ("1e+100",),
        "from 1 to 1e+10",
    ),
    Case(
        "yaml-key-twice",
        Y,
        "learning_rate written twice in one entry",
        lambda f: _load_config(
            f,
            path=f.text("twice.yml", f"{ENV_ID}:\n  n_timesteps: 8\n  learning_rate: 1e-4\n  learning_rate: 3e-4\n"),
        ),
        TrainingError,
        ("twice.yml", "'learning_rate'", "lines 3 and 4"),
        "written twice",
    ),
    Case(
        "model-truncated",
        MF,
        "validate_checkpoint(<first half of a COMA zip>)",
        lambda f: _validate(f.truncated_zip),
        CheckpointError,
        ("truncated.zip",),
        "truncated",
    ),
    Case(
        "model-bit-rot",
        MF,
        "validate_checkpoint(<COMA zip with a damaged byte in policy.pth>)",
        lambda f: _validate(f.crc_zip),
        CheckpointError,
        ("bitrot.zip", "'policy.pth'"),
        "fails its CRC check",
    ),
    Case(
        "model-member-not-torch",
        MF,
        "load_checkpoint(<COMA zip whose policy.pth is not a torch file>)",
        lambda f: _load_checkpoint(f.badpth_zip, f),
        CheckpointError,
        ("badpth.zip",),
        "corrupt",
    ),
    Case(
        "model-other-algorithm",
        MF,
        "validate_checkpoint(<a PPO model zip>)",
        lambda f: _validate(f.ppo_zip),
        CheckpointError,
        ("ppo.zip", "ActorCriticPolicy"),
        "is not a COMA checkpoint",
    ),
    Case(
        "model-resume-uav-count",
        MF,
        'train(resume=<2-UAV zip>, env="env1", set env_kwargs.n_uavs=3)',
        lambda f: _train(f, resume=f.coma_zip, env="env1", config=f.config(), overrides={"env_kwargs.n_uavs": 3}),
        TrainingError,
        ("coma_2uavs.zip", "2 UAVs", "has 3"),
        None,
    ),
    Case(
        "model-resume-warm-start-without-reference",
        MF,
        'train(resume=<a COMA zip without a KL reference>, env="env1", config=<an entry with warm_start>)',
        lambda f: _train(
            f,
            resume=f.coma_zip,
            env="env1",
            config=f.config("warm.yml", {ENV_ID: {**TINY[ENV_ID], "warm_start": {"rounds": 1, "missions": 2}}}),
        ),
        TrainingError,
        ("coma_2uavs.zip", "no KL reference actor"),
        "start a new run",
    ),
    Case(
        "model-resume-not-a-run",
        MF,
        'train(resume="<tmp>/maps")  # a folder without config.yml',
        lambda f: _train(f, resume=f.path("maps")),
        TrainingError,
        ("maps",),
        "not a run folder",
    ),
    Case(
        "model-num_timesteps-not-a-number",
        MF,
        'validate_checkpoint(<COMA zip whose data has "num_timesteps": "abc">)',
        lambda f: _validate(f.bad_steps_zip),
        CheckpointError,
        ("badsteps.zip", "'num_timesteps'", "'abc'"),
        "a whole number of joint steps",
    ),
    Case(
        "checkpoint-disk-full",
        MF,
        'atomic_save(model, "<tmp>/models/previous.zip")  # the disk fills up (ENOSPC)',
        _save_on_full_disk,
        DiskFullError,
        ("previous.zip", "no space left"),
        "its previous version is intact",
    ),
    # ------------------------------------------------------------------ SenDFuse weight files
    Case(
        "weights-truncated",
        W,
        "load_weights(<first half of a weight file>)",
        lambda f: _load_weights(f.weights_truncated),
        SenDFuseWeightsError,
        ("truncated.safetensors",),
        "truncated or corrupt",
    ),
    Case(
        "weights-foreign",
        W,
        "load_weights(<a safetensors file of another program>)",
        lambda f: _load_weights(f.weights_foreign),
        SenDFuseWeightsError,
        ("foreign.safetensors", "'pt'"),
        "expected 'sb3_coma.sendfuse'",
    ),
    Case(
        "weights-bit-flip",
        W,
        "load_weights(<weight file with one flipped byte>)",
        lambda f: _load_weights(f.weights_bitflip),
        SenDFuseWeightsError,
        ("bitflip.safetensors",),
        "does not match its checksum",
    ),
    Case(
        "weights-nan",
        W,
        "load_weights(<weights of a diverged training>)",
        lambda f: _load_weights(f.weights_nan),
        SenDFuseWeightsError,
        ("nan.safetensors", "NaN"),
        None,
    ),
    Case(
        "weights-config-mismatch",
        W,
        'load_weights(<R=40 file>, expected_config={"grid_size": 44})',
        lambda f: _load_weights(f.weights_r40, expected_config={"grid_size": 44}),
        SenDFuseWeightsError,
        ("r40.safetensors", "file has 40"),
        "expected 44",
    ),
    # ------------------------------------------------------------------ evaluate()
    Case(
        "evaluate-method-unknown",
        EV,
        'evaluate("bogus")',
        lambda f: _evaluate("bogus"),
        ValueError,
        ("'bogus'",),
        "ag, lawnmower, oracle, random",
    ),
    Case(
        "evaluate-workers-zero",
        EV,
        'evaluate("random", n_trials=20, workers=0)',
        lambda f: _evaluate("random", n_trials=20, workers=0),
        ValueError,
        ("workers=0",),
        "an integer >= 1",
    ),
    Case(
        "vec-env-workers-without-main-guard",
        E,
        "python script.py  # make_vec_env(..., workers=2) at the script's top level, without the guard",
        _unguarded_script,
        RuntimeError,
        ("make_vec_env(workers=2)", "script.py' (line 2)"),
        'if __name__ == "__main__":',
    ),
    Case(
        "evaluate-seed-bool",
        EV,
        'evaluate("random", seed=True)',
        lambda f: _evaluate("random", seed=True),
        ValueError,
        ("seed=True",),
        "an integer >= 0",
    ),
    Case(
        "evaluate-n_trials-zero",
        EV,
        'evaluate("random", n_trials=0)',
        lambda f: _evaluate("random", n_trials=0),
        ValueError,
        ("n_trials=0",),
        "an integer >= 1",
    ),
    Case(
        "evaluate-not-a-policy",
        EV,
        "evaluate(object())",
        lambda f: _evaluate(object()),
        TypeError,
        ("object",),
        "an object with SB3's predict",
    ),
    Case(
        "evaluate-model-truncated",
        EV,
        'evaluate("<tmp>/models/truncated.zip", fusion="mean")',
        lambda f: _evaluate(str(f.truncated_zip), fusion="mean", n_uavs=2, budget=2),
        CheckpointError,
        ("truncated.zip",),
        "truncated",
    ),
    Case(
        "evaluate-ag-lookahead-too-deep",
        EV,
        'evaluate("ag", planner_kwargs={"lookahead": 9})',
        lambda f: _evaluate("ag", n_trials=1, n_uavs=2, budget=2, planner_kwargs={"lookahead": 9}),
        ValueError,
        ("lookahead=9",),
        "an integer from 1 (greedy AG) to",
    ),
    Case(
        "evaluate-planner-option",
        EV,
        'evaluate("lawnmower", planner_kwargs={"altitude": 7.0})',
        lambda f: _evaluate("lawnmower", n_uavs=2, budget=2, planner_kwargs={"altitude": 7.0}),
        ValueError,
        ("altitude=7.0",),
        "[5.0, 10.0, 15.0]",
    ),
    Case(
        "evaluate-team-size-differs",
        EV,
        "evaluate(<zip trained with 2 UAVs>, n_uavs=4)  # a warning: legal, per-agent actor",
        lambda f: _as_error(lambda: _evaluate(str(f.trained_zip), n_uavs=4, budget=2)),
        UserWarning,
        ("2 UAVs", "flies with 4"),
        "allowed",
    ),
    Case(
        "evaluate-fusion-differs",
        EV,
        'evaluate(<zip trained with fusion "mean">, fusion="sendfuse")  # a warning',
        lambda f: _as_error(lambda: _evaluate(str(f.trained_zip), n_uavs=2, budget=2, fusion="sendfuse")),
        UserWarning,
        ("'mean'", "'sendfuse'"),
        "pass fusion='mean'",
    ),
    # ------------------------------------------------------------------ reliability v3
    Case(
        "env-reward-metrics-weighted-entropy",
        E,
        'make_env("env1", reward="metrics", reward_entropy="weighted")',
        lambda f: uav_ipp.make_env("env1", reward="metrics", reward_entropy="weighted"),
        ConfigError,
        ("reward_entropy='weighted'", "reward='metrics'"),
        "drop reward_entropy",
    ),
    Case(
        "config-split-test-without-permission",
        Y,
        'load_config(set env_kwargs.split="test")',
        lambda f: _load_config(f, {"env_kwargs.split": "test"}),
        TrainingError,
        ("split='test'",),
        "--allow-test-split",
    ),
    Case(
        "config-allow-test-split-ignored",
        Y,
        "load_config(set env_kwargs.allow_test_split=True)  # the entry trains on another split",
        lambda f: _load_config(f, {"env_kwargs.allow_test_split": True}),
        TrainingError,
        ("allow_test_split=True", "split='paper'"),
        "is ignored",
    ),
    Case(
        "config-warm_start-teacher",
        Y,
        'load_config(set warm_start.teacher="random")',
        lambda f: _load_config(f, {"warm_start.teacher": "random"}),
        TrainingError,
        ("teacher='random'",),
        "'oracle'",
    ),
    Case(
        "config-warm_start-rounds",
        Y,
        "load_config(set warm_start.rounds=0)",
        lambda f: _load_config(f, {"warm_start.rounds": 0}),
        TrainingError,
        ("rounds=0",),
        "an integer >= 1",
    ),
    Case(
        "config-count-not-whole",
        Y,
        'load_config(set n_timesteps="1.005e1")  # 10.05 joint steps',
        lambda f: _load_config(f, {"n_timesteps": "1.005e1"}),
        TrainingError,
        ("n_timesteps", "10.05"),
        "a whole number",
    ),
    Case(
        "weights-shipped-replaced",
        W,
        'make_vec_env("env1", fusion="sendfuse")  # the package\'s sendfuse_r44.safetensors was replaced',
        _replaced_shipped_weights,
        SenDFuseWeightsError,
        ("sendfuse_r44.safetensors", "SHA-256"),
        "pass your own file",
    ),
    Case(
        "model-shipped-replaced-by-path",
        MF,
        'evaluate("<package>/coma_env1.zip")  # the shipped file was replaced, given by its path',
        _replaced_shipped_model,
        PretrainedError,
        ("coma_env1.zip", "checksum mismatch"),
        "NOT loaded",
    ),
    Case(
        "evaluate-observation-option-differs",
        EV,
        "evaluate(<zip trained with lattice 11>, lattice=9)",
        lambda f: _evaluate(str(f.trained_zip), n_uavs=2, budget=2, lattice=9),
        ValueError,
        ("lattice=11", "lattice=9"),
        "drop lattice=",
    ),
    Case(
        "evaluate-world-differs",
        EV,
        "evaluate(<zip trained with budget 4>, budget=2, noise='loud')  # a warning",
        lambda f: _as_error(lambda: _evaluate(str(f.trained_zip), n_uavs=2, budget=2, noise="loud")),
        WorldMismatchWarning,
        ("budget=2 (trained: 4)", "noise='loud' (trained: 'moderate')"),
        "allowed",
    ),
    # ------------------------------------------------------------------ CLI
    CliCase(
        "cli-evaluate-out-holds-user-files",
        "sb3-coma evaluate ... --out <a folder of the user's own files>",
        _foreign_out,
        ("my_results", "thesis.xlsx"),
        "pass an empty or new folder",
    ),
    CliCase(
        "cli-train-run-dir-hidden",
        "sb3-coma train --run-dir .",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--run-dir", "."],
        ("'.'",),
        None,
    ),
    CliCase(
        "cli-train-threads-zero",
        "sb3-coma train --threads 0",
        lambda f: ["train", "--threads", "0"],
        ("--threads", "0"),
        "an integer >= 1",
    ),
    CliCase(
        "cli-train-env-unknown",
        "sb3-coma train --env env9",
        lambda f: ["train", "--env", "env9"],
        ("'env9'",),
        "env1, env2, env3",
    ),
    CliCase(
        "cli-train-config-missing",
        "sb3-coma train --config <tmp>/missing.yml",
        lambda f: ["train", "--env", "env1", "--config", str(f.path("missing.yml"))],
        ("missing.yml",),
        "does not exist",
    ),
    CliCase(
        "cli-train-variant-unknown",
        "sb3-coma train --config tiny.yml --variant nope",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--variant", "nope"],
        ("'nope'",),
        "variants: loud",
    ),
    CliCase(
        "cli-train-set-bad-env-option",
        "sb3-coma train --set env_kwargs.noise=quiet",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--set", "env_kwargs.noise=quiet"],
        ("noise='quiet'",),
        "['loud', 'moderate', 'none']",
    ),
    CliCase(
        "cli-train-set-misspelt-key",
        "sb3-coma train --set batch_sise=8",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--set", "batch_sise=8"],
        ("'batch_sise'",),
        "did you mean 'batch_size'",
    ),
    CliCase(
        "cli-train-set-gamma",
        "sb3-coma train --set gamma=2",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--set", "gamma=2"],
        ("gamma", "got 2"),
        "[0, 1]",
    ),
    CliCase(
        "cli-train-timesteps-zero",
        "sb3-coma train --timesteps 0",
        lambda f: ["train", "--env", "env1", "--timesteps", "0"],
        ("--timesteps", "got 0"),
        ">= 1",
    ),
    CliCase(
        "cli-train-device-unknown",
        "sb3-coma train --device tpu",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--device", "tpu"],
        ("'tpu'",),
        "use auto, cpu, cuda",
    ),
    CliCase(
        "cli-train-device-no-cuda",
        "sb3-coma train --device cuda  # no GPU here",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--device", "cuda"],
        ("'cuda'",),
        "no CUDA device is available",
        within=_no_gpu,
    ),
    CliCase(
        "cli-train-run-dir-below-a-file",
        "sb3-coma train --run-dir <tmp>/a_file/sub  # a_file is a file",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--run-dir", str(f.a_file / "sub")],
        ("a_file/sub", "a_file is a file"),
        "cannot be made",
    ),
    CliCase(
        "cli-train-disk-full",
        "sb3-coma train ...  # the disk fills up at the second checkpoint",
        lambda f: [
            "train",
            "--env",
            "env1",
            "--config",
            str(f.config()),
            "--timesteps",
            "16",
            "--save-freq",
            "8",
            "--set",
            "n_steps=8",
            "--run-dir",
            str(f.path("runs/disk_full")),
            "--no-progress",
            "-v",
            "0",
        ],
        ("rl_model_16_steps.zip", "no space left"),
        "no partial file was left",
        rc=1,
        within=lambda: _disk_full_after(1),
    ),
    CliCase(
        "cli-train-fusion-kwargs",
        "sb3-coma train --set 'env_kwargs.fusion_kwargs={alpha: 2}'",
        lambda f: [
            "train",
            "--env",
            "env1",
            "--config",
            str(f.config()),
            "--set",
            "env_kwargs.fusion_kwargs={alpha: 2}",
        ],
        ("{'alpha': 2}", "['alpha']"),
        "no options",
    ),
    CliCase(
        "cli-train-resume-missing",
        "sb3-coma train --resume <tmp>/nowhere",
        lambda f: ["train", "--resume", str(f.path("nowhere"))],
        ("nowhere",),
        "no such file or folder",
    ),
    CliCase(
        "cli-train-resume-truncated",
        "sb3-coma train --resume <truncated checkpoint>",
        lambda f: ["train", "--resume", str(f.truncated_zip)],
        ("truncated.zip",),
        "truncated",
    ),
    CliCase(
        "cli-train-resume-other-algorithm",
        "sb3-coma train --resume <a PPO zip>",
        lambda f: ["train", "--resume", str(f.ppo_zip)],
        ("ppo.zip",),
        "not a COMA checkpoint",
    ),
    CliCase(
        "cli-ablation-training-logs-empty",
        "sb3-coma ablation --models <tmp> --training-logs <tmp>/empty",
        lambda f: ["ablation", "--models", str(f.root), "--training-logs", str(f.folder("empty"))],
        ("empty",),
        "{fusion}_{extractor}",
    ),
    CliCase(
        "cli-evaluate-method-unknown",
        "sb3-coma evaluate --methods bogus",
        lambda f: ["evaluate", "--methods", "bogus", "--trials", "1"],
        ("'bogus'",),
        "ag, lawnmower, oracle, random",
    ),
    CliCase(
        "cli-evaluate-trials-zero",
        "sb3-coma evaluate --trials 0",
        lambda f: ["evaluate", "--methods", "random", "--trials", "0"],
        ("--trials", "got 0"),
        ">= 1",
    ),
    CliCase(
        "cli-evaluate-model-missing",
        "sb3-coma evaluate --methods '' --model <tmp>/none.zip",
        lambda f: ["evaluate", "--methods", "", "--model", str(f.path("none.zip"))],
        ("none.zip",),
        "not found",
    ),
    CliCase(
        "cli-evaluate-model-path-with-equals-missing",
        "sb3-coma evaluate --methods '' --model <tmp>/sweep/lr=0.001/none.zip  # named whole, not split at '='",
        lambda f: ["evaluate", "--methods", "", "--model", str(f.path("sweep/lr=0.001/none.zip"))],
        ("sweep/lr=0.001/none.zip",),
        "not found",
    ),
    CliCase(
        "cli-evaluate-model-corrupt",
        "sb3-coma evaluate --methods '' --model <damaged zip> --fusion mean",
        lambda f: [
            "evaluate",
            "--methods",
            "",
            "--model",
            str(f.crc_zip),
            "--fusion",
            "mean",
            "--env",
            "env1",
            "--uavs",
            "2",
            "--budget",
            "2",
            "--trials",
            "1",
            "--no-plots",
        ],
        ("bitrot.zip",),
        "fails its CRC check",
    ),
    CliCase(
        "cli-evaluate-map-path-missing",
        "sb3-coma evaluate --map-path nope.png",
        lambda f: ["evaluate", "--methods", "random", "--map-path", str(f.path("nope.png"))],
        ("nope.png",),
        "not found",
    ),
    CliCase(
        "cli-evaluate-noise-unknown",
        "sb3-coma evaluate --env env1 --noise quiet",
        lambda f: ["evaluate", "--methods", "random", "--env", "env1", "--noise", "quiet", "--trials", "1"],
        ("noise='quiet'",),
        "['loud', 'moderate', 'none']",
    ),
    CliCase(
        "cli-export-out-is-a-file",
        "sb3-coma export --model env1 --out <tmp>/a_file  # a file, not a folder",
        lambda f: ["export", "--model", "env1", "--out", str(f.a_file)],
        ("a_file",),
        "is an existing file",
    ),
    CliCase(
        "cli-export-model-is-a-baseline",
        "sb3-coma export --model ag --out <tmp>/onnx",
        lambda f: ["export", "--model", "ag", "--out", str(f.path("onnx"))],
        ("'ag'",),
        "is a baseline planner",
    ),
    CliCase(
        "cli-evaluate-out-is-a-file",
        "sb3-coma evaluate --out <tmp>/a_file  # a file, not a folder",
        lambda f: [*_QUICK_EVALUATE, "--out", str(f.a_file)],
        ("a_file",),
        "is a file, not a folder",
    ),
    CliCase(
        "cli-evaluate-out-below-a-file",
        "sb3-coma evaluate --out <tmp>/a_file/sub.csv",
        lambda f: [*_QUICK_EVALUATE, "--out", str(f.a_file / "sub.csv")],
        ("a_file/sub.csv", "a_file"),
        "its parent",
    ),
    CliCase(
        "cli-evaluate-out-table-is-a-folder",
        "sb3-coma evaluate --out <tmp>/out  # out/table.csv is a folder",
        lambda f: [*_QUICK_EVALUATE, "--out", str(f.folder("out/table.csv").parent)],
        ("table.csv",),
        "is a folder",
    ),
    CliCase(
        "cli-demo-uavs-zero",
        "sb3-coma demo --env env1 --uavs 0",
        lambda f: ["demo", "--env", "env1", "--uavs", "0"],
        ("--uavs", "got 0"),
        "an integer >= 1",
    ),
    CliCase(
        "cli-demo-seed-negative",
        "sb3-coma demo --seed -1",
        lambda f: ["demo", "--seed", "-1"],
        ("--seed", "got -1"),
        "an integer from 0 to 4294967295",
    ),
    CliCase(
        "cli-evaluate-uavs-text",
        "sb3-coma evaluate --uavs two",
        lambda f: [*_QUICK_EVALUATE, "--uavs", "two"],
        ("--uavs", "'two'"),
        "an integer >= 1",
    ),
    CliCase(
        "cli-train-set-split-test",
        "sb3-coma train --set env_kwargs.split=test",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--set", "env_kwargs.split=test"],
        ("split='test'",),
        "--allow-test-split",
    ),
    CliCase(
        "cli-train-allow-test-split-with-resume",
        "sb3-coma train --resume RUN --allow-test-split",
        lambda f: ["train", "--resume", str(f.path("nowhere")), "--allow-test-split"],
        ("--allow-test-split", "--resume"),
        "is ignored",
    ),
    CliCase(
        "cli-train-set-count-not-whole",
        "sb3-coma train --set n_timesteps=1.005e1",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--set", "n_timesteps=1.005e1"],
        ("n_timesteps", "10.05"),
        "a whole number",
    ),
    CliCase(
        "cli-train-run-dir-not-text",
        "sb3-coma train --run-dir $'bad\\xff'  # not valid UTF-8",
        lambda f: ["train", "--env", "env1", "--config", str(f.config()), "--run-dir", BAD_NAME],
        ("--run-dir", "bad\\udcff"),
        "not valid utf-8 text",
    ),
    CliCase(
        "cli-evaluate-env-twice",
        "sb3-coma evaluate --env env1,UavIpp-Env1-v0",
        lambda f: ["evaluate", "--methods", "random", "--env", "env1,UavIpp-Env1-v0", "--trials", "1"],
        ("'UavIpp-Env1-v0'", "twice"),
        "each map once",
    ),
    CliCase(
        "cli-evaluate-out-not-text",
        "sb3-coma evaluate --out $'bad\\xff'  # not valid UTF-8",
        lambda f: [*_QUICK_EVALUATE, "--out", BAD_NAME],
        ("--out", "bad\\udcff"),
        "not valid utf-8 text",
    ),
    CliCase(
        "cli-evaluate-model-is-a-folder",
        "sb3-coma evaluate --methods '' --model <tmp>/maps  # a folder, not a zip",
        lambda f: ["evaluate", "--methods", "", "--model", str(f.folder("maps")), "--trials", "1"],
        ("maps' is a folder",),
        "pass the model .zip inside it",
    ),
    CliCase(
        "cli-export-opset-out-of-range",
        "sb3-coma export --model env1 --out <tmp>/onnx --opset 99",
        lambda f: ["export", "--model", "env1", "--out", str(f.path("onnx")), "--opset", "99"],
        ("--opset 99",),
        "from 17 to",
    ),
    CliCase(
        "cli-export-fusion-differs",
        "sb3-coma export --model <zip trained with fusion mean> --fusion sendfuse",
        lambda f: ["export", "--model", str(f.trained_zip), "--out", str(f.path("onnx")), "--fusion", "sendfuse"],
        ("--fusion sendfuse", "'mean'"),
        "must not claim a fusion",
    ),
    CliCase(
        "cli-export-out-not-text",
        "sb3-coma export --model env1 --out $'bad\\xff'  # not valid UTF-8",
        lambda f: ["export", "--model", "env1", "--out", BAD_NAME],
        ("--out", "bad\\udcff"),
        "not valid utf-8 text",
    ),
    CliCase(
        "cli-noise-sweep-arm-other-map",
        "sb3-coma noise-sweep --env env3 --arms env1",
        lambda f: ["noise-sweep", "--quick", "--env", "env3", "--arms", "env1", "--out", str(f.path("sweep"))],
        ("model of env1", "flies env3"),
        "sweep it on env1",
    ),
    CliCase(
        "cli-noise-sweep-arms-twice",
        "sb3-coma noise-sweep --arms ag,ag",
        lambda f: ["noise-sweep", "--quick", "--env", "env1", "--arms", "ag,ag", "--out", str(f.path("sweep"))],
        ("['ag']", "twice"),
        "each arm once",
    ),
    CliCase(
        "cli-noise-sweep-out-is-a-file",
        "sb3-coma noise-sweep --out <tmp>/a_file  # a file, not a folder",
        lambda f: ["noise-sweep", "--quick", "--arms", "ag", "--out", str(f.a_file)],
        ("a_file",),
        "is a file",
    ),
    CliCase(
        "cli-reproduce-trials-one",
        "sb3-coma reproduce --quick --trials 1",
        lambda f: ["reproduce", "--quick", "--trials", "1", "--out", str(f.path("repro"))],
        ("--trials 1",),
        "at least 2 missions",
    ),
    CliCase(
        "cli-reproduce-env-twice",
        "sb3-coma reproduce --env env1,env1",
        lambda f: ["reproduce", "--quick", "--env", "env1,env1", "--out", str(f.path("repro"))],
        ("'env1'", "twice"),
        "each map once",
    ),
    CliCase(
        "cli-reproduce-out-is-a-file",
        "sb3-coma reproduce --out <tmp>/a_file  # a file, not a folder",
        lambda f: ["reproduce", "--quick", "--out", str(f.a_file)],
        ("a_file",),
        "is a file",
    ),
]


# =============================================================================== running a case
def run_cli(argv: list[str], within: Callable[[], contextlib.AbstractContextManager[Any]] = contextlib.nullcontext):
    from sb3_coma import cli

    err = io.StringIO()
    with within(), contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = cli.main(argv)
    return rc, err.getvalue()


def observe(case: Case | CliCase, files: Files) -> tuple[str, str]:
    """``(what the user sees as the error, the message)`` for the docs."""
    if isinstance(case, CliCase):
        rc, err = run_cli(case.argv(files), case.within)
        return f"exit {rc}, stderr", err.strip()
    try:
        case.run(files)
    except BaseException as exc:  # we report whatever comes out
        return type(exc).__name__, str(exc)
    return "no error", ""


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("bad_input")
    f = Files(root)
    yield f
    f.close()
    torch.set_num_threads(threads)


@pytest.fixture
def in_tmp(files, monkeypatch):
    monkeypatch.chdir(files.root)  # default run folders / results land in the temporary folder


def test_catalogue_is_large_and_ids_are_unique():
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids))
    assert len(ids) >= 30


@pytest.mark.parametrize("case", [c for c in CASES if isinstance(c, Case)], ids=lambda c: c.id)
def test_bad_input_raises_named_error(case: Case, files, in_tmp):
    with pytest.raises(BaseException) as info:
        case.run(files)
    exc = info.value
    assert type(exc) is case.error, f"{case.id}: expected {case.error.__name__}, got {type(exc).__name__}: {exc}"
    message = str(exc)
    for needle in case.names:
        assert needle in message, f"{case.id}: the message does not name {needle!r}: {message}"
    if case.allowed is not None:
        assert case.allowed in message, (
            f"{case.id}: the message does not say what is allowed ({case.allowed!r}): {message}"
        )


@pytest.mark.parametrize("case", [c for c in CASES if isinstance(c, CliCase)], ids=lambda c: c.id)
def test_cli_bad_input_is_one_line_exit_2(case: CliCase, files, in_tmp, capsys):
    from sb3_coma import cli

    argv = case.argv(files)
    capsys.readouterr()
    with case.within():
        rc = cli.main(argv)
    err = capsys.readouterr().err
    assert rc == case.rc, f"{case.id}: exit status {rc}, stderr: {err}"
    lines = err.strip().splitlines()
    assert len(lines) == 1, f"{case.id}: expected one stderr line, got: {err}"
    assert lines[0].startswith(f"sb3-coma {argv[0]}: error: ")
    assert "Traceback" not in err
    for needle in case.names:
        assert needle in lines[0], f"{case.id}: the message does not name {needle!r}: {lines[0]}"
    if case.allowed is not None:
        assert case.allowed in lines[0], f"{case.id}: the message does not say what is allowed: {lines[0]}"


def test_docs_list_every_case():
    text = DOC.read_text(encoding="utf-8")
    missing = [c.id for c in CASES if f"`{c.id}`" not in text]
    assert not missing, f"docs/errors.md lacks {missing}; regenerate with python tests/test_errors_catalogue.py"


# =============================================================================== when, and what is left
def test_a_missing_gpu_is_refused_before_the_run_folder_is_made(files, in_tmp):
    with _no_gpu(), pytest.raises(TrainingError, match="no CUDA device"):
        _train(files, env="env1", config=files.config(), device="cuda:1", run_dir=files.path("runs/gpu"))
    assert not files.path("runs/gpu").exists()


def test_a_full_disk_keeps_the_previous_checkpoint(files, in_tmp, capsys):
    from sb3_coma import cli
    from sb3_coma.common.checkpoints import validate_checkpoint

    run = files.path("runs/full_disk")
    argv = ["train", "--env", "env1", "--config", str(files.config()), "--timesteps", "16", "--save-freq", "8"]
    with _disk_full_after(1):
        rc = cli.main([*argv, "--set", "n_steps=8", "--run-dir", str(run), "--no-progress", "-v", "0"])
    assert rc == 1, capsys.readouterr().err
    assert validate_checkpoint(run / "checkpoints" / "rl_model_8_steps.zip").num_timesteps == 8
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["rl_model_8_steps.zip"]  # no .tmp left
    with pytest.raises(DiskFullError):
        _save_on_full_disk(files)
    assert files.path("models/previous.zip").read_bytes() == files.coma_zip.read_bytes()


@pytest.mark.parametrize("value", ["batch_size:abc", "batch_size:'abc'"])
def test_zoo_bad_params_are_one_line_exit_2(value, files, in_tmp, capsys):
    from sb3_coma.app import zoo

    log = str(files.path("zoo_logs"))
    rc = zoo.main(["train", "--env", ENV_ID, "-n", "8", "--eval-freq", "-1", "-f", log, "-params", value])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith("sb3_coma.app.zoo train: error: ") and "batch_size" in err[0] and "'abc'" in err[0]


def test_a_model_flown_as_trained_gives_no_mismatch_warning(files, in_tmp):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _evaluate(str(files.trained_zip), n_uavs=2, budget=2)
        _evaluate(str(files.trained_zip), n_uavs=2, budget=2, fusion="mean")
    assert not [w for w in caught if "was trained with" in str(w.message)]


# =============================================================================== known gaps
# Bad input that still leaks an unhelpful message, in code other owners are editing
# (sb3_coma/coma, sb3_coma/extractors.py), found by this catalogue and fixed since.
def test_gap_coma_ent_coef_text(files):
    with pytest.raises(ValueError, match=r"ent_coef.*'x'"):
        _coma(files, ent_coef="x")


def test_gap_coma_seed_text(files):
    with pytest.raises((TypeError, ValueError), match=r"seed.*'a'"):
        _coma(files, seed="a")


def test_gap_coma_features_dim_zero(files):
    with pytest.raises(ValueError, match=r"features_dim.*0"):
        _coma(files, policy_kwargs={"features_extractor_kwargs": {"features_dim": 0}})


def test_gap_coma_learn_negative_timesteps(files):
    model = _coma(files)
    with pytest.raises(ValueError, match=r"total_timesteps.*-5"):
        model.learn(-5)


def test_gap_coma_stats_window_zero(files):
    with pytest.raises(ValueError, match=r"stats_window_size.*0"):
        _coma(files, stats_window_size=0)


# =============================================================================== property tests
ANY_VALUE = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=6),
    st.lists(st.one_of(st.integers(-20, 20), st.floats(-20, 20), st.text(max_size=2)), max_size=4),
    st.dictionaries(
        st.one_of(st.integers(0, 20), st.text(max_size=2)), st.one_of(st.floats(-1, 1), st.text(max_size=2)), max_size=3
    ),
    st.lists(st.tuples(st.integers(-5, 55), st.integers(-5, 55), st.sampled_from([5, 10, 15, 7])), max_size=5),
)
OPTION_NAMES = sorted(f for f in uav_ipp.IppConfig.__dataclass_fields__ if f != "map_name")
FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(options=st.dictionaries(st.sampled_from(OPTION_NAMES), ANY_VALUE, min_size=1, max_size=3))
def test_any_env_option_value_is_accepted_or_a_config_error(options):
    """Whatever a user passes, validation answers with a ConfigError naming the option, never
    with a TypeError/ValueError/IndexError from inside."""
    try:
        uav_ipp.IppConfig.from_options("env1", **options)
    except ConfigError as exc:
        assert str(exc).startswith("invalid option "), exc


@FAST
@given(
    rule=st.one_of(
        st.text(max_size=14),
        st.builds(
            lambda k, v: f"{k}:{v}",
            st.sampled_from(["threshold", "dark", "hottest", "coldest", "exg", "ndvi", "otsu", "x"]),
            st.one_of(st.floats(), st.text(max_size=4)),
        ),
        ANY_VALUE,
    )
)
def test_any_valuable_rule_parses_or_is_a_map_error(rule):
    from uav_ipp.maps import parse_rule

    try:
        parsed = parse_rule(rule)
    except MapError as exc:
        assert "rule" in str(exc)
    else:
        assert parsed.kind in uav_ipp.maps.RULE_NAMES


@settings(
    max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture]
)
@given(
    value=st.one_of(
        ANY_VALUE,
        st.integers(0, 5),
        st.sampled_from([np.int64(3), np.float32(2.0), np.array(4), float("inf"), np.float64("-inf")]),
    )
)
def test_any_action_value_steps_or_is_refused_naming_the_agent(files, value):
    env = files.env
    if not env.agents:
        env.reset(seed=0)
    try:
        env.step({"uav_0": value, "uav_1": 0})
    except (ValueError, TypeError) as exc:
        assert "uav_0" in str(exc) and "0..5" in str(exc)


# =============================================================================== docs generator
def _markdown(files: Files) -> str:
    """One section per surface: a table of id, bad input, error type and the real message."""
    root = str(files.root)
    sections: dict[str, list[str]] = {}
    for case in CASES:
        kind, message = observe(case, files)
        message = message.replace(root, "<tmp>").replace(str(DOC.parent.parent), "<repo>")
        message = message.replace("|", "\\|").replace("\n", " ")
        bad = case.bad_input.replace("|", "\\|")
        sections.setdefault(case.surface, []).append(f"| `{case.id}` | `{bad}` | {kind} | {message} |")
    out = []
    for surface, rows in sections.items():
        out += [
            f"### {surface}",
            "",
            "| id | bad input | error | message (as the user sees it) |",
            "| --- | --- | --- | --- |",
            *rows,
            "",
        ]
    return "\n".join(out)


if __name__ == "__main__":  # pragma: no cover - maintainer tool for docs/errors.md
    import warnings

    warnings.filterwarnings("ignore")
    tmp = Path(tempfile.mkdtemp(prefix="sb3coma_errors_"))
    import os

    os.chdir(tmp)
    f = Files(tmp)
    try:
        sys.stdout.write(_markdown(f))
    finally:
        f.close()
        shutil.rmtree(tmp, ignore_errors=True)
