"""Five classes of bad input (issue #44), each answered by one rule and tested as a class.

1. :class:`TestNoDataFills`: a float raster's NoData fills (-3.4028235e+38, float64's lowest,
   -9999, the value a TIFF declares in ``GDAL_NODATA``) are no data, like transparent pixels,
   with one warning naming the fill and its pixels and cells; not the coldest valuable ground.
2. :class:`TestPathsWithEquals`: a model path that exists is a path even when it holds ``=``;
   ``LABEL=PATH`` still labels.
3. :class:`TestMainGuard`: worker processes started from a script's unguarded top level are one
   line naming ``if __name__ == "__main__":``, not "a worker process died (out of memory?)".
4. :class:`TestGenericPoliciesOnDicts`: SB3's one-input ``CnnPolicy`` / ``MlpPolicy`` on what they
   cannot read are one ``ValueError`` pointing at ``MultiInputPolicy`` / ``UavCnnPolicy``.
5. :class:`TestNoLogFolder`: ``learn()`` of every shipped algorithm (COMA, IPPO, MAPPO) leaves no
   ``SB3-<timestamp>`` folder in the temp dir, and still logs.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import runpy
import subprocess
import sys
import tempfile
import textwrap
import time
import uuid
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from gymnasium import spaces
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import uav_ipp
from uav_ipp import MapError

TINY_WORLD = {"n_uavs": 2, "budget": 4}
PROPERTY = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _cli(argv: list[str]) -> tuple[int, str, str]:
    """``sb3-coma ARGV`` in this process: (exit status, stdout, stderr)."""
    from sb3_coma import cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main(argv)
    return rc, out.getvalue(), err.getvalue()


def _one_error_line(err: str, command: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"sb3-coma {command}: error: "), err
    assert "Traceback" not in err
    return lines[0]


# ================================================================================ 1. NoData fills
FLOAT32_LOWEST = float(np.finfo(np.float32).min)


def _write_tiff(path: Path, values: np.ndarray, declared: str | None = None) -> Path:
    """A float32 TIFF (PIL, mode F), with a ``GDAL_NODATA`` tag when ``declared`` is given."""
    from PIL import Image, TiffImagePlugin

    tags = TiffImagePlugin.ImageFileDirectory_v2()
    if declared is not None:
        tags[42113] = declared
        tags.tagtype[42113] = 2  # ASCII, as GDAL writes it
    Image.fromarray(values.astype(np.float32)).save(path, tiffinfo=tags)
    return path


def _fill_value(fill: str) -> float:
    return {"float32-lowest": FLOAT32_LOWEST, "-9999": -9999.0, "declared -32768": -32768.0, "declared nan": math.nan}[
        fill
    ]


def _field(seed: int, side: int, fraction: float, fill: str) -> tuple[np.ndarray, np.ndarray]:
    """(a float32 raster of temperatures with ``fill`` in some pixels, where the fills are)."""
    rng = np.random.default_rng(seed)
    values = rng.uniform(250.0, 320.0, (side, side)).astype(np.float32)
    holes = rng.random((side, side)) < fraction
    values[holes] = _fill_value(fill)
    return values, holes


class TestNoDataFills:
    """The rule: in ``uav_ipp.maps.rules._decode`` / ``read_image`` a pixel holding a fill becomes
    transparent (alpha 0) and leaves the stretch of the float values; ``_load_file`` warns once."""

    FILLS = ("float32-lowest", "-9999", "declared -32768", "declared nan")

    @staticmethod
    def _declared(fill: str) -> str | None:
        return fill.split()[1] if fill.startswith("declared") else None

    @PROPERTY
    @given(
        seed=st.integers(0, 2**32 - 1),
        side=st.integers(6, 24),
        fraction=st.floats(0.05, 0.6),
        fill=st.sampled_from(FILLS),
    )
    def test_fills_are_no_data_and_the_rest_reads_as_without_them(self, seed, side, fraction, fill):
        from uav_ipp.maps.rules import read_image

        values, holes = _field(seed, side, fraction, fill)
        assume(holes.any() and (~holes).sum() >= 4)
        with tempfile.TemporaryDirectory() as tmp:
            image = read_image(_write_tiff(Path(tmp) / "dem.tif", values, self._declared(fill)))
            # the same raster with the holes holding an ordinary value (its coldest): what the data reads as
            plain = values.copy()
            plain[holes] = values[~holes].min()
            reference = read_image(_write_tiff(Path(tmp) / "plain.tif", plain))
        assert image.alpha is not None and reference.alpha is None
        np.testing.assert_array_equal(image.alpha, np.where(holes, 0.0, 1.0))
        np.testing.assert_allclose(image.gray[~holes], reference.gray[~holes], atol=1e-6)
        assert sum(n for _, n in image.nodata) == int(holes.sum())

    @PROPERTY
    @given(
        seed=st.integers(0, 2**32 - 1),
        side=st.integers(8, 24),
        fraction=st.floats(0.05, 0.5),
        fill=st.sampled_from(FILLS),
    )
    def test_a_fill_is_never_the_coldest_valuable_ground(self, seed, side, fraction, fill):
        from uav_ipp.maps import load_ground_truth

        values, holes = _field(seed, side, fraction, fill)
        assume(holes.any() and (~holes).sum() >= 8)
        with tempfile.TemporaryDirectory() as tmp:
            path = _write_tiff(Path(tmp) / f"dem-{uuid.uuid4().hex}.tif", values, self._declared(fill))
            with pytest.warns(UserWarning) as caught:
                truth = load_ground_truth("mine", map_path=path, valuable="coldest:0.3", grid=side, lattice=2)
        assert not truth.valuable[holes].any()  # grid == pixels: a fill cell is a no-data cell
        assert truth.valuable[~holes].any()
        messages = [str(w.message) for w in caught if "no data" in str(w.message)]
        assert len(messages) == 1 and "\n" not in messages[0], messages
        n = int(holes.sum())
        shown = {"float32-lowest": "-3.4028235e+38", "-9999": "-9999"}.get(fill, self._declared(fill) or "")
        assert f"NoData fill {shown}" in messages[0]
        assert f"{n:,} of {side * side:,} pixels" in messages[0]
        assert f"{n:,} of {side * side:,} grid cells are mostly no data" in messages[0]

    def test_float64_lowest_and_a_fill_in_one_band_of_a_colour_raster(self, tmp_path):
        import cv2

        from uav_ipp.maps.rules import read_image

        dem = np.linspace(0.0, 50.0, 400).reshape(20, 20)
        dem[:5] = np.finfo(np.float64).min
        cv2.imwrite(str(tmp_path / "d64.tif"), dem)
        colour = np.random.default_rng(0).uniform(0, 10, (20, 20, 3)).astype(np.float32)
        colour[:, :4, 1] = -9999.0
        cv2.imwrite(str(tmp_path / "c3.tif"), colour)
        d64, c3 = read_image(tmp_path / "d64.tif"), read_image(tmp_path / "c3.tif")
        assert d64.nodata == (("-1.7976931348623157e+308 (float64 lowest)", 100),)
        assert c3.nodata == (("-9999", 80),)
        assert d64.alpha is not None and (d64.alpha[:5] == 0).all() and (d64.alpha[5:] == 1).all()
        assert d64.gray[5:].min() == 0.0 and d64.gray[5:].max() == 1.0  # the stretch of the data alone

    def test_integer_images_and_unfilled_floats_are_left_as_they_are(self, tmp_path):
        import cv2

        from uav_ipp.maps.rules import read_image

        gray = np.zeros((16, 16), np.uint8)
        gray[8:] = 200
        cv2.imwrite(str(tmp_path / "dark.png"), gray)  # 0 is black ground, not a fill
        image = read_image(tmp_path / "dark.png")
        assert image.alpha is None and image.nodata == ()
        floats = _write_tiff(tmp_path / "t.tif", np.linspace(-50.0, 50.0, 256).reshape(16, 16))
        assert read_image(floats).nodata == ()

    def test_only_fills_is_one_map_error_and_exit_2_on_the_cli(self, tmp_path):
        from uav_ipp.maps import load_ground_truth

        empty = _write_tiff(tmp_path / "void.tif", np.full((12, 12), -9999.0))
        with pytest.raises(MapError, match=r"holds only NoData pixels \(the NoData fill -9999\); nothing to map"):
            load_ground_truth("mine", map_path=empty, grid=12, lattice=2)
        rc, _, err = _cli(
            [
                *("evaluate", "--methods", "random", "--map-path", str(empty), "--trials", "1", "--uavs", "2"),
                *("--budget", "2", "--no-plots", "--out", str(tmp_path / "out")),
            ]
        )
        assert rc == 2
        assert "void.tif' holds only NoData pixels" in _one_error_line(err, "evaluate")
        assert not (tmp_path / "out").exists()


# ================================================================================ 2. paths with '='
@pytest.fixture(scope="module")
def model_zip(tmp_path_factory) -> Path:
    """A COMA zip for 2 UAVs (untrained: only its path matters), in ``sweep/lr=0.001/``."""
    from sb3_coma import COMA

    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", **TINY_WORLD)
    model = COMA(
        "UavCnnPolicy", venv, batch_size=8, seed=0, policy_kwargs={"features_extractor_kwargs": {"features_dim": 16}}
    )
    path = tmp_path_factory.mktemp("sweep") / "lr=0.001" / "model.zip"
    path.parent.mkdir()
    model.save(path)
    venv.close()
    return path


PATH_PART = st.text(alphabet="ab_.-019=", min_size=1, max_size=8).filter(lambda s: s not in (".", ".."))


class TestPathsWithEquals:
    """The rule: ``sb3_coma.app.methods.split_label``, used by ``sb3-coma evaluate --model`` /
    ``--training-log`` and ``sb3-coma ablation --model``."""

    @PROPERTY
    @given(
        parts=st.lists(PATH_PART, min_size=1, max_size=3),
        zip_suffix=st.booleans(),
        label=st.from_regex(r"[a-z][a-z0-9_]{0,6}", fullmatch=True),
    )
    def test_an_existing_path_is_a_path_and_label_path_still_labels(self, parts, zip_suffix, label):
        from sb3_coma.app.methods import split_label

        assume(any("=" in part for part in parts))
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp, *parts[:-1], parts[-1] + ".zip")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"PK")
            given_path = str(path) if zip_suffix else str(path)[: -len(".zip")]
            assert split_label(given_path) == (None, given_path)
            assert split_label(f"{label}={given_path}") == (label, given_path)
            assert split_label(f" {label} = {given_path} ") == (label, given_path)
        # gone: a spelt-out path is still named whole, a bare label=path still splits
        assert split_label(given_path) == (None, given_path)
        assert split_label(f"{label}=nowhere.zip") == (label, "nowhere.zip")

    def test_cli_evaluate_flies_a_path_with_equals_bare_and_labelled(self, model_zip, tmp_path):
        out = tmp_path / "out"
        argv = ["evaluate", "--methods", "", "--model", str(model_zip), "--model", f"lr={model_zip}", "--env", "env1"]
        rc, _, err = _cli([*argv, "--trials", "1", "--uavs", "2", "--budget", "4", "--no-plots", "--out", str(out)])
        assert rc == 0, err
        table = (out / "table.md").read_text()
        assert "| coma1 |" in table and "| lr |" in table

    def test_the_python_front_door_takes_the_path_too(self, model_zip):
        import sb3_coma

        result = sb3_coma.evaluate(str(model_zip), env="env1", n_trials=1, **TINY_WORLD)
        assert result.method == "model"

    def test_a_missing_path_with_equals_is_named_whole(self, model_zip, tmp_path):
        missing = model_zip.parent / "none.zip"
        rc, _, err = _cli(["evaluate", "--methods", "", "--model", str(missing), "--trials", "1"])
        assert rc == 2
        assert f"model file not found: {str(missing)!r}" in _one_error_line(err, "evaluate")

    def test_ablation_wants_a_label_even_for_a_path_with_equals(self, model_zip):
        rc, _, err = _cli(["ablation", "--model", str(model_zip), "--trials", "1"])
        assert rc == 2
        line = _one_error_line(err, "ablation")
        assert "FUSION_EXTRACTOR=PATH" in line and repr(str(model_zip)) in line


# ================================================================================ 3. the __main__ guard
UNGUARDED = {
    "make_vec_env": """
        import uav_ipp
        venv = uav_ipp.make_vec_env("env1", n_envs=2, n_uavs=2, budget=4, workers=2)
        venv.reset()
    """,
    "evaluate": """
        import sb3_coma
        sb3_coma.evaluate("random", env="env1", n_trials=2, n_envs=1, workers=2, n_uavs=2, budget=4)
    """,
}


#: script body -> whether the call is refused
GUARD_LAYOUTS = {
    'if __name__ == "__main__":\n    CALL\n': False,
    'def main():\n    CALL\n\nif __name__ == "__main__":\n    main()\n': False,
    'if "__main__" == __name__:\n    CALL\n': False,
    "try:\n    if __name__ == '__main__':\n        CALL\nfinally:\n    pass\n": False,
    "CALL\n": True,
    "def main():\n    CALL\n\nmain()\n": True,
    "for _ in range(1):\n    CALL\n": True,
}


def _run_as_main(path: Path) -> None:
    """Run ``path`` as the main script of this process (as ``python path`` would)."""
    runpy.run_path(str(path), run_name="__main__")


class TestMainGuard:
    """The rule: ``uav_ipp.workers.check_main_guard``, called before any spawn / forkserver
    process starts (``WorkerVecEnv``'s pipes, ``evaluate``'s pool)."""

    @pytest.mark.parametrize("what", sorted(UNGUARDED))
    def test_a_script_without_the_guard_is_one_line_and_fails_fast(self, what, tmp_path):
        script = tmp_path / f"{what}_script.py"
        script.write_text(textwrap.dedent(UNGUARDED[what]))
        start = time.monotonic()
        done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
        assert done.returncode != 0
        assert time.monotonic() - start < 60
        last = done.stderr.strip().splitlines()[-1]
        assert last.startswith(f"RuntimeError: {what}(workers=2) starts worker processes"), done.stderr
        assert 'if __name__ == "__main__":' in last and f"{str(script)!r} (line 3)" in last
        assert "bootstrapping phase" not in done.stderr and "out of memory" not in done.stderr

    @pytest.mark.parametrize(
        ("body", "refused"), GUARD_LAYOUTS.items(), ids=[f"layout{k}" for k in range(len(GUARD_LAYOUTS))]
    )
    @pytest.mark.parametrize("start_method", ["spawn", "forkserver", "fork"])
    def test_every_guard_spelling_passes_and_every_unguarded_call_is_refused(
        self, body, refused, start_method, tmp_path
    ):
        call = f"__import__('uav_ipp.workers').workers.check_main_guard('x(workers=2)', {start_method!r})"
        script = tmp_path / "script.py"
        script.write_text("import uav_ipp\n" + body.replace("CALL", call))
        if refused and start_method != "fork":  # a forked child does not re-run the script
            with pytest.raises(RuntimeError, match=r'outside `if __name__ == "__main__":`') as info:
                _run_as_main(script)
            assert "\n" not in str(info.value)
        else:
            _run_as_main(script)

    def test_code_that_is_not_a_script_is_never_refused(self):
        from uav_ipp.workers import check_main_guard

        check_main_guard("x", "spawn")  # pytest's own __main__ (a package's __main__ or a guarded script)
        done = subprocess.run(
            [sys.executable, "-c", "from uav_ipp.workers import check_main_guard; check_main_guard('x', 'spawn')"],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr


# ================================================================================ 4. CnnPolicy / MlpPolicy on a Dict
@pytest.fixture(scope="module")
def uav_venv():
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", **TINY_WORLD)
    yield venv
    venv.close()


VECTOR = spaces.Box(-1.0, 1.0, (5,), np.float32)
IMAGE = spaces.Box(0, 255, (3, 36, 40), np.uint8)
SMALL_IMAGE = spaces.Box(0, 255, (1, 8, 8), np.uint8)
FLOAT_IMAGE = spaces.Box(0.0, 1.0, (3, 36, 36), np.float32)
LEAVES = st.sampled_from([VECTOR, IMAGE, SMALL_IMAGE, FLOAT_IMAGE])
OBSERVATIONS = st.one_of(
    LEAVES,
    st.dictionaries(st.sampled_from(["a", "b", "c"]), LEAVES, min_size=1, max_size=3).map(spaces.Dict),
    st.dictionaries(st.sampled_from(["a", "b"]), LEAVES, min_size=1, max_size=2).map(
        lambda d: spaces.Dict({**d, "action_mask": spaces.Box(0, 1, (3,), np.int8)})
    ),
)


def _reads_it(policy: str, actor_space: spaces.Space) -> bool:
    """What SB3's one-input extractor of ``policy`` reads (the expected outcome)."""
    if isinstance(actor_space, spaces.Dict):
        return False
    return policy == "MlpPolicy" or actor_space in (IMAGE,)


class TestGenericPoliciesOnDicts:
    """The rule: ``sb3_coma.coma.policies._check_extractor_fits``, in ``COMAPolicy.__init__``."""

    @pytest.mark.parametrize("policy", ["CnnPolicy", "MlpPolicy"])
    def test_the_uav_world_with_a_generic_policy_is_one_line_naming_the_right_ones(self, policy, uav_venv):
        from sb3_coma import COMA

        with pytest.raises(ValueError) as info:
            COMA(policy, uav_venv, batch_size=8)
        message = str(info.value)
        assert "\n" not in message and f"policy {policy!r}" in message
        assert "'MultiInputPolicy'" in message and "'UavCnnPolicy'" in message
        assert "['action_gain', 'local']" in message

    def test_the_policies_that_read_it_still_build(self, uav_venv):
        from sb3_coma import COMA

        COMA("MultiInputPolicy", uav_venv, batch_size=8)
        COMA("UavCnnPolicy", uav_venv, batch_size=8, policy_kwargs={"features_extractor_kwargs": {"features_dim": 16}})

    @PROPERTY
    @given(space=OBSERVATIONS, policy=st.sampled_from(["CnnPolicy", "MlpPolicy"]))
    def test_any_space_builds_and_predicts_or_is_one_value_error(self, space, policy):
        import torch as th

        from sb3_coma.coma import policies
        from sb3_coma.common.joint import actor_observation_space

        cls = getattr(policies, policy)
        state = spaces.Box(0.0, 1.0, (4,), np.float32)
        try:
            built = cls(space, spaces.Discrete(3), lambda _: 3e-4, n_agents=2, state_space=state)
        except ValueError as exc:
            assert not _reads_it(policy, actor_observation_space(space)), exc
            assert "\n" not in str(exc) and str(exc).startswith(f"policy {policy!r}")
            return
        assert _reads_it(policy, actor_observation_space(space))
        with th.no_grad():
            action, _ = built.predict(space.sample())
        assert 0 <= int(np.asarray(action).reshape(-1)[0]) < 3

    def test_train_with_cnn_policy_is_exit_2_and_leaves_no_run(self, tmp_path):
        config = {
            "UavIpp-Env1-v0": {
                "n_timesteps": 8,
                "n_envs": 1,
                "policy": "CnnPolicy",
                "batch_size": 8,
                "env_kwargs": {"fusion": "mean", **TINY_WORLD},
            }
        }
        path = tmp_path / "cnn.yml"
        path.write_text(yaml.safe_dump(config))
        rc, _, err = _cli(["train", "--env", "env1", "--config", str(path), "--run-dir", str(tmp_path / "run")])
        assert rc == 2
        assert "policy 'CnnPolicy' (NatureCNN)" in _one_error_line(err, "train")
        assert not (tmp_path / "run").exists()


# ================================================================================ 5. no SB3-* folder
def _build(algorithm: str, venv: Any, verbose: int) -> Any:
    """A shipped algorithm through its public constructor, small."""
    from sb3_coma import COMA
    from sb3_coma.mappo import make_ippo, make_mappo

    if algorithm == "coma":
        policy = "UavCnnPolicy" if "local" in getattr(venv.observation_space, "spaces", {}) else "MlpPolicy"
        kwargs = (
            {"policy_kwargs": {"features_extractor_kwargs": {"features_dim": 16}}} if policy == "UavCnnPolicy" else {}
        )
        return COMA(
            policy,
            venv,
            n_steps=8,
            batch_size=8,
            n_epochs=1,
            n_critic_epochs=1,
            verbose=verbose,
            device="cpu",
            **kwargs,
        )
    factory = {"ippo": make_ippo, "mappo": make_mappo}[algorithm]
    return factory(venv, n_steps=8, batch_size=16, n_epochs=1, verbose=verbose, device="cpu")


def _spread_venv():
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    from sb3_coma import make_marl_vec_env

    return make_marl_vec_env(
        lambda: simple_spread_v3.parallel_env(N=2, max_cycles=8, continuous_actions=False), n_envs=1, seed=0
    )


class TestNoLogFolder:
    """The rule: ``sb3_coma.common.logger`` (COMA's ``_setup_learn``, the IPPO / MAPPO factories)."""

    @pytest.mark.parametrize("world", ["uav", "generic"])
    @pytest.mark.parametrize("algorithm", ["coma", "ippo", "mappo"])
    def test_learn_leaves_no_folder_and_still_logs(self, algorithm, world, tmp_path, monkeypatch, capsys):
        monkeypatch.setenv("TMPDIR", str(tmp_path))
        monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
        venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", **TINY_WORLD) if world == "uav" else _spread_venv()
        model = _build(algorithm, venv, verbose=1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # SB3's "n_steps * n_envs not a multiple of batch_size"
            model.learn(16)
            model.learn(16, reset_num_timesteps=False)
        venv.close()
        assert not list(tmp_path.glob("SB3-*")), os.listdir(tmp_path)
        assert "total_timesteps" in capsys.readouterr().out  # verbose=1 still prints SB3's table

    def test_tensorboard_keeps_its_own_folder(self, tmp_path, monkeypatch):
        pytest.importorskip("tensorboard")
        from sb3_coma.mappo import make_ippo

        monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
        venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", **TINY_WORLD)
        model = make_ippo(venv, n_steps=8, batch_size=16, n_epochs=1, tensorboard_log=str(tmp_path / "tb"))
        model.learn(16)
        venv.close()
        assert list((tmp_path / "tb").iterdir())
