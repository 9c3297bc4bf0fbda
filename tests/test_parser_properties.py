"""Property tests of the two parsers users feed by hand (#36): any image file is either read into
finite grey levels in [0, 1] or refused with one MapError line; any YAML config text is either a
config or one TrainingError line (never a traceback from deep inside, never a silent default)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sb3_coma.app.config import TrainingError
from uav_ipp.maps import MapError
from uav_ipp.maps.rules import read_image

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

DTYPES = (np.uint8, np.uint16, np.float32, np.float64, np.int16, np.bool_)


@st.composite
def images(draw: st.DrawFn) -> np.ndarray:
    """Arrays OpenCV can write: 1-5 channels, odd sizes, any dtype here, NaN / inf / constant fills."""
    dtype = draw(st.sampled_from(DTYPES))
    shape = (draw(st.integers(1, 9)), draw(st.integers(1, 9)), draw(st.sampled_from([0, 1, 2, 3, 4])))
    shape = shape[:2] if shape[2] == 0 else shape
    fill = draw(st.sampled_from(["random", "zeros", "nan", "inf", "max"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    a = rng.uniform(0, 1, shape)
    if fill == "zeros":
        a = np.zeros(shape)
    elif fill in ("nan", "inf"):
        a.flat[0] = np.nan if fill == "nan" else np.inf
    if dtype is np.bool_:
        return (a > 0.5).astype(np.uint8) * 255
    if np.issubdtype(dtype, np.integer):
        top = np.iinfo(dtype).max if fill == "max" else 200
        return np.nan_to_num(a * top, nan=0, posinf=top).astype(dtype)
    return a.astype(dtype)


@SETTINGS
@given(image=images(), suffix=st.sampled_from([".png", ".tiff", ".bmp", ".jpg"]))
def test_any_image_reads_to_grey_in_the_unit_range_or_is_one_map_error(tmp_path: Path, image, suffix) -> None:
    path = tmp_path / f"map{suffix}"
    try:
        written = cv2.imwrite(str(path), image)
    except cv2.error:
        written = False
    if not written:
        return  # a combination the format cannot hold: nothing for a user to load
    try:
        read = read_image(path)
    except MapError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)
        return
    assert np.isfinite(read.gray).all() and read.gray.min() >= 0.0 and read.gray.max() <= 1.0
    assert read.gray.shape == image.shape[:2]


VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-5, 10**6), st.floats(allow_nan=True), st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=6,
)
KEYS = st.sampled_from(
    ["learning_rate", "n_envs", "policy", "policy_kwargs", "kl_coef", "kl_fraction", "normalize_advantage",
     "gamma", "gae_lambda", "n_steps", "batch_size", "n_critic_epochs", "unknown_key", "max_grad_norm"]
)  # fmt: skip
_ENV = {"n_uavs": 2, "budget": 2}


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(entry=st.dictionaries(KEYS, VALUES, max_size=3))
def test_any_config_entry_builds_a_model_or_is_one_training_error(tmp_path: Path, entry) -> None:
    """Loading and building the model: a value COMA would take wrongly (a string for a bool, a list
    for a number) must stop here with one line naming it, not run with a silent meaning."""
    import uav_ipp
    from sb3_coma.app.training import build_model, plan_run

    path = tmp_path / "coma.yml"
    path.write_text(yaml.safe_dump({"UavIpp-Env1-v0": {"n_timesteps": 8, "env_kwargs": _ENV, **entry}}))
    try:
        plan = plan_run(env="env1", config=path, seed=0, device="cpu")
    except TrainingError as exc:
        assert "\n" not in str(exc).strip()
        return
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="sendfuse", **_ENV)
    try:
        model = build_model(plan, venv, device="cpu")
    except TrainingError as exc:
        assert "\n" not in str(exc).strip()
        return
    finally:
        venv.close()
    for key in ("normalize_advantage",):
        if key in entry:
            assert isinstance(getattr(model, key), bool)
