"""Validated, typed options of the IPP environment.

Every option a user can pass to :func:`uav_ipp.make_env` lives here with its default
(docs/design.md, "The world"). ``IppConfig.from_options(**options)`` is the single place where user input is
checked, so a bad value fails at construction with a message naming the option, the value and
what is allowed, instead of a traceback from deep inside a footprint kernel.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NoReturn, TypeGuard

import numpy as np

#: Version of the world's rules. 2: per-cell local beliefs M_i fed by cell-level messages (issue #14);
#: 1: local beliefs on the comm grid. A model trained on another version sees different observations.
WORLD_VERSION = 2

#: Channel-noise presets of the paper on received images, ``I_r = a I + n``: (lower bound of the
#: attenuation ``a ~ U(alpha_low, 1)``, sigma of ``n ~ N(0, sigma^2)``), per cell.
NOISE_PRESETS: dict[str, tuple[float, float]] = {
    "none": (1.0, 0.0),
    "moderate": (0.8, 0.02),
    "loud": (0.6, 0.06),
}

#: ``attenuation``: the paper's ``a ~ U(alpha_low, 1)`` on every link, or a lower bound that falls
#: linearly from 1 at distance 0 to ``alpha_low`` at ``comm_range``.
ATTENUATIONS = ("uniform", "distance")
#: ``decoder``: how a receiver folds ``I_r`` into its local map (docs/environment.md, decision 7).
DECODERS = ("soft", "threshold")
#: ``split``: the paper's fixed mission, or the train / test mission distributions.
SPLITS = ("paper", "train", "test")
#: ``start``: the split's own rule (None), fixed well-spread columns, or seeded random columns.
STARTS = ("fixed", "random")
#: Rewards are float32 in SB3's buffers: scales beyond this would overflow to inf.
MAX_REWARD_SCALE = 1e30

#: ``reward`` options: the paper's relative entropy drop, or the change of the two Table I metrics.
REWARDS = ("entropy", "metrics")
#: ``observation``: "v2" (8 actor channels, 3 critic state channels) or "v3" (adds the fine
#: whole-field view of M_i and teammates' intent on board, ground-truth channels for the critic;
#: docs/environment.md, "Observation v3").
OBSERVATIONS = ("v2", "v3")

DEFAULT_FLIP_PROBABILITY: dict[float, float] = {5.0: 0.01, 10.0: 0.265, 15.0: 0.375}
DEFAULT_STARTS: tuple[tuple[float, float, float], ...] = (
    (10.0, 10.0, 15.0),
    (40.0, 10.0, 15.0),
    (40.0, 40.0, 15.0),
    (10.0, 40.0, 15.0),
)


class ConfigError(ValueError):
    """A user-facing option has a bad value; the message names the option and what is allowed."""


def invalid_option(option: str, value: Any, allowed: str) -> NoReturn:
    """The one way the world refuses an option: one line naming it, its value and what is allowed
    (the config's own checks, the env's start columns, the vec env's copies and workers)."""
    raise ConfigError(f"invalid option {option}={value!r}: {allowed}")


# The world's number predicates (sb3_coma has its own, sb3_coma.common.numbers: the world imports
# nothing of the learner). ``bool`` is a subclass of ``int`` (``isinstance(True, int)`` holds, so
# ``True`` would pass as 1), and numpy's scalars are no subclasses of ``int`` or ``float`` (except
# ``np.float64``), so ``isinstance(value, int)`` alone both lets ``True`` in and keeps
# ``np.int64(3)`` out.
def is_flag(value: Any) -> TypeGuard[bool]:
    """True or False: a ``bool`` or numpy's ``np.bool_`` (which is not a ``bool`` subclass)."""
    return isinstance(value, (bool, np.bool_))


def is_whole(value: Any) -> TypeGuard[int]:
    """An integer: an ``int`` or a numpy integer (``np.int64`` is not an ``int`` subclass), never a
    flag (``True`` is an ``int``)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def is_real(value: Any) -> TypeGuard[float]:
    """A real number: an ``int``, a ``float`` or a numpy integer or floating scalar (``np.float32``
    is not a ``float`` subclass), never a flag. NaN and inf are numbers: ranges are the caller's."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def plain(value: Any) -> Any:
    """A numpy scalar as the Python ``bool``, ``int`` or ``float`` it holds (YAML, JSON and a saved
    model's record take only those); anything else as it is."""
    return value.item() if isinstance(value, (np.bool_, np.integer, np.floating)) else value


def _real(value: Any) -> float:
    """``float(value)`` for the numbers of a list option; a flag is refused (``TypeError``)."""
    if is_flag(value):
        raise TypeError(f"{value!r} is a flag, not a number")
    return float(value)


@dataclass(frozen=True)
class IppConfig:
    """All options of one environment instance (frozen: an env never changes its rules mid-run)."""

    map_name: str = "env3"
    map_path: str | None = None
    valuable: str | None = None
    map_seed: int | None = 0
    n_uavs: int = 4
    budget: int = 15
    field_size: float = 50.0
    grid: int = 493
    lattice: int = 11
    altitudes: tuple[float, ...] = (5.0, 10.0, 15.0)
    flip_probability: Mapping[float, float] = field(default_factory=lambda: dict(DEFAULT_FLIP_PROBABILITY))
    fov_deg: float = 60.0
    split: str = "paper"
    mission_from_seed: bool = False
    start: str | None = None
    start_positions: tuple[tuple[float, float, float], ...] | None = None
    start_altitude: float = 15.0
    comm_range: float = 25.0
    drop_probability: float = 0.0
    noise: str = "moderate"
    alpha_low: float | None = None
    sigma: float | None = None
    attenuation: str = "uniform"
    decoder: str = "soft"
    comm_grid: int = 44
    alpha: float = 10.0
    beta: float = -0.17
    reward_entropy: str = "plain"
    reward: str = "entropy"
    action_gain: bool = True
    observation: str = "v2"
    render_mode: str | None = None

    def __post_init__(self) -> None:
        """Valid by construction: every ``IppConfig`` (direct, :meth:`from_options`, :meth:`replace`)
        is checked once, here, so the env and the vec-env builders that receive one trust it. A numpy
        scalar option (``np.int64(3)``, ``np.float32(0.5)``, ``np.bool_(True)``) is kept as the Python
        number it holds, so the config's record (YAML, JSON) takes it."""
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, plain(getattr(self, f.name)))
        self.validate()

    # ------------------------------------------------------------------ derived values
    @property
    def spacing(self) -> float:
        """Distance between neighbouring lattice positions in metres (5 m by default)."""
        return self.field_size / (self.lattice - 1)

    @property
    def cell_size(self) -> float:
        """Side of one belief cell in metres (about 0.1014 m by default)."""
        return self.field_size / self.grid

    @property
    def noise_params(self) -> tuple[float, float]:
        """(alpha_low, sigma) of the channel: the preset's, overridden by explicit options."""
        preset_low, preset_sigma = NOISE_PRESETS[self.noise]
        low = preset_low if self.alpha_low is None else float(self.alpha_low)
        sigma = preset_sigma if self.sigma is None else float(self.sigma)
        return low, sigma

    @property
    def start_rule(self) -> str:
        """``start`` if given, else the split's rule: fixed corners for "paper", random otherwise."""
        if self.start is not None:
            return self.start
        return "fixed" if self.split == "paper" else "random"

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_options(cls, name: str = "env3", **options: Any) -> IppConfig:
        """Build a config from ``make_env`` keyword options, rejecting unknown or bad ones."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ConfigError(
                f"unknown environment option(s) {unknown}; allowed options: {sorted(known - {'map_name'})}"
            )
        if "map_name" in options:
            raise ConfigError("pass the map as the first argument (name=...), not as map_name=")
        if "altitudes" in options and options["altitudes"] is not None:
            try:
                options["altitudes"] = tuple(_real(a) for a in options["altitudes"])
            except (TypeError, ValueError):
                invalid_option("altitudes", options["altitudes"], "a non-empty list of positive altitudes in metres")
        if "flip_probability" in options and options["flip_probability"] is not None:
            fp = options["flip_probability"]
            if not isinstance(fp, Mapping):
                invalid_option("flip_probability", fp, "a mapping altitude -> flip probability")
            try:
                options["flip_probability"] = {_real(k): _real(v) for k, v in fp.items()}
            except (TypeError, ValueError):
                invalid_option("flip_probability", fp, "a mapping altitude (m) -> flip probability (numbers)")
        if options.get("start_positions") is not None:
            try:
                options["start_positions"] = tuple(tuple(_real(c) for c in p) for p in options["start_positions"])
            except (TypeError, ValueError):
                invalid_option("start_positions", options["start_positions"], "a list of (x, y, z) triples in metres")
        return cls(map_name=str(name), **options)

    def replace(self, **changes: Any) -> IppConfig:
        """A copy with some options changed (validated by construction)."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ validation
    def validate(self) -> None:
        """Check every option; raise :class:`ConfigError` naming the first bad one.

        The checks run in a fixed order (lattice and sizes, altitudes, sensor, starts, channel,
        communication, reward, the rest), so the option a message names does not depend on
        which other options are also bad.
        """
        self._validate_sizes()
        self._validate_altitudes()
        self._validate_flip_probability()
        self._validate_starts()
        self._validate_channel()
        self._validate_comm()
        self._validate_reward()
        self._validate_outputs()

    def _validate_sizes(self) -> None:
        """``lattice``, ``grid``, ``n_uavs``, ``budget`` and ``field_size``."""
        if not is_whole(self.lattice) or self.lattice < 2:
            invalid_option("lattice", self.lattice, "an integer >= 2")
        if not is_whole(self.grid) or self.grid < self.lattice:
            invalid_option("grid", self.grid, f"an integer >= lattice ({self.lattice})")
        if not is_whole(self.n_uavs) or self.n_uavs < 1:
            invalid_option("n_uavs", self.n_uavs, "an integer >= 1")
        if self.n_uavs > self.lattice * self.lattice:
            invalid_option("n_uavs", self.n_uavs, f"at most {self.lattice * self.lattice} (one UAV per lattice column)")
        if not is_whole(self.budget) or self.budget < 1:
            invalid_option("budget", self.budget, "an integer >= 1 (decisions per UAV)")
        if not (is_real(self.field_size) and math.isfinite(self.field_size) and self.field_size > 0):
            invalid_option("field_size", self.field_size, "a positive number of metres")

    def _validate_altitudes(self) -> None:
        """At most 3 positive, strictly increasing, equally spaced altitudes."""
        if not self.altitudes or any(not math.isfinite(a) or a <= 0 for a in self.altitudes):
            invalid_option("altitudes", self.altitudes, "a non-empty list of positive altitudes in metres")
        if len(self.altitudes) > 3:
            invalid_option(
                "altitudes",
                self.altitudes,
                "at most 3 altitude levels (the gain kernels carry 3 columns per weighting)",
            )
        if list(self.altitudes) != sorted(set(self.altitudes)):
            invalid_option("altitudes", self.altitudes, "strictly increasing altitudes")
        if len(self.altitudes) > 1:
            steps = {round(b - a, 9) for a, b in zip(self.altitudes, self.altitudes[1:])}
            if len(steps) != 1:
                invalid_option("altitudes", self.altitudes, "equally spaced altitudes (up/down move one level)")

    def _validate_flip_probability(self) -> None:
        """One flip probability in (0, 0.5) for every altitude."""
        if not isinstance(self.flip_probability, Mapping):
            invalid_option("flip_probability", self.flip_probability, "a mapping altitude (m) -> flip probability")
        missing = [a for a in self.altitudes if a not in self.flip_probability]
        if missing:
            invalid_option(
                "flip_probability", dict(self.flip_probability), f"an entry for every altitude; missing {missing}"
            )
        for alt, q in self.flip_probability.items():
            if not (0.0 < q < 0.5):
                invalid_option(
                    "flip_probability",
                    dict(self.flip_probability),
                    f"probabilities strictly between 0 and 0.5 (altitude {alt} has {q})",
                )

    def _validate_starts(self) -> None:
        """``fov_deg``, ``start``, ``split``, ``mission_from_seed``, ``start_altitude`` and ``start_positions``."""
        if not (is_real(self.fov_deg) and 0 < self.fov_deg < 180):
            invalid_option("fov_deg", self.fov_deg, "an angle in (0, 180) degrees")
        if self.start is not None and self.start not in STARTS:
            invalid_option("start", self.start, "None (the split's rule), 'fixed' or 'random'")
        if self.split not in SPLITS:
            invalid_option("split", self.split, f"one of {list(SPLITS)}")
        if self.split != "paper" and self.map_path is not None:
            invalid_option(
                "split",
                self.split,
                "'paper' with map_path= (a user's image has no train / test scenes); "
                "use start='random' for random starts on it",
            )
        if not is_flag(self.mission_from_seed):
            invalid_option("mission_from_seed", self.mission_from_seed, "True or False")
        if self.mission_from_seed and self.split == "paper":
            invalid_option("mission_from_seed", True, "False with split='paper' (the paper's mission is fixed)")
        if not is_real(self.start_altitude) or self.start_altitude not in self.altitudes:
            invalid_option("start_altitude", self.start_altitude, f"one of the altitudes {list(self.altitudes)}")
        if self.start_positions is not None:
            self._validate_start_positions(self.start_positions)

    def _validate_channel(self) -> None:
        """``noise``, ``alpha_low``, ``sigma``, ``attenuation`` and ``decoder``."""
        if not isinstance(self.noise, str) or self.noise not in NOISE_PRESETS:
            invalid_option("noise", self.noise, f"one of {sorted(NOISE_PRESETS)}")
        if self.alpha_low is not None and not (is_real(self.alpha_low) and 0.0 <= self.alpha_low <= 1.0):
            invalid_option(
                "alpha_low", self.alpha_low, "None (the noise preset's) or a lower attenuation bound in [0, 1]"
            )
        if self.sigma is not None and not (is_real(self.sigma) and math.isfinite(self.sigma) and self.sigma >= 0):
            invalid_option("sigma", self.sigma, "None (the noise preset's) or a noise standard deviation >= 0")
        if self.attenuation not in ATTENUATIONS:
            invalid_option("attenuation", self.attenuation, f"one of {list(ATTENUATIONS)}")
        if self.decoder not in DECODERS:
            invalid_option("decoder", self.decoder, f"one of {list(DECODERS)}")

    def _validate_comm(self) -> None:
        """``comm_range``, ``drop_probability`` and ``comm_grid``."""
        if not (is_real(self.comm_range) and self.comm_range >= 0 and not math.isnan(self.comm_range)):
            invalid_option("comm_range", self.comm_range, "a distance >= 0 in metres (inf for unlimited)")
        if not (is_real(self.drop_probability) and 0.0 <= self.drop_probability <= 1.0):
            invalid_option("drop_probability", self.drop_probability, "a probability in [0, 1]")
        if not is_whole(self.comm_grid) or self.comm_grid < 4 or self.comm_grid % 4 or self.comm_grid > self.grid:
            invalid_option("comm_grid", self.comm_grid, f"a multiple of 4 between 4 and grid ({self.grid})")

    def _validate_reward(self) -> None:
        """``alpha``, ``beta``, ``reward_entropy``, ``reward`` and the pair of the last two."""
        if not (is_real(self.alpha) and is_real(self.beta) and math.isfinite(self.alpha) and math.isfinite(self.beta)):
            invalid_option("alpha/beta", (self.alpha, self.beta), "finite reward scale and offset")
        if max(abs(self.alpha), abs(self.beta)) > MAX_REWARD_SCALE:
            invalid_option(
                "alpha/beta",
                (self.alpha, self.beta),
                f"magnitudes at most {MAX_REWARD_SCALE:g}: larger rewards overflow float32 to inf",
            )
        if self.reward_entropy not in ("plain", "weighted"):
            invalid_option(
                "reward_entropy",
                self.reward_entropy,
                "'plain' (binary entropy of every cell) or 'weighted' (ipp-marl's class weighting)",
            )
        if self.reward not in REWARDS:
            invalid_option(
                "reward",
                self.reward,
                "'entropy' (the paper's entropy-drop reward) or 'metrics' (the change of F1 and valuable-cell entropy)",
            )
        self._validate_reward_pair()

    def _validate_outputs(self) -> None:
        """``action_gain``, ``observation``, ``render_mode`` and ``map_seed``."""
        if not is_flag(self.action_gain):
            invalid_option(
                "action_gain", self.action_gain, "True (observe each action's expected information gain) or False"
            )
        if self.observation not in OBSERVATIONS:
            invalid_option("observation", self.observation, f"one of {list(OBSERVATIONS)}")
        if self.observation == "v3" and self.comm_grid % self.lattice:
            invalid_option(
                "comm_grid",
                self.comm_grid,
                f"a multiple of lattice ({self.lattice}) with observation='v3' (its fine view)",
            )
        if self.render_mode not in (None, "rgb_array", "ansi"):
            invalid_option("render_mode", self.render_mode, "None, 'rgb_array' or 'ansi'")
        if self.map_seed is not None and (not is_whole(self.map_seed) or self.map_seed < 0):
            invalid_option("map_seed", self.map_seed, "None (a new map each reset, env1 only) or an integer >= 0")

    def _validate_reward_pair(self) -> None:
        """``reward_entropy`` shapes only the entropy-drop reward: with ``reward="metrics"`` a
        weighted entropy would be ignored while the run's config claims it, so the pair is refused."""
        if self.reward == "metrics" and self.reward_entropy == "weighted":
            invalid_option(
                "reward_entropy",
                self.reward_entropy,
                "not with reward='metrics', which ignores it (it weights the 'entropy' reward only); "
                "drop reward_entropy or use reward='entropy'",
            )

    def _validate_start_positions(self, positions: tuple[tuple[float, float, float], ...]) -> None:
        if len(positions) != self.n_uavs:
            invalid_option("start_positions", positions, f"exactly n_uavs={self.n_uavs} positions")
        columns = set()
        for p in positions:
            if len(p) != 3:
                invalid_option("start_positions", positions, "(x, y, z) triples")
            x, y, z = p
            for coord in (x, y):
                k = coord / self.spacing
                if not (0 <= coord <= self.field_size) or abs(k - round(k)) > 1e-6:
                    invalid_option(
                        "start_positions",
                        p,
                        f"x and y on the lattice: multiples of {self.spacing:g} m in [0, {self.field_size:g}]",
                    )
            if z not in self.altitudes:
                invalid_option("start_positions", p, f"z one of the altitudes {list(self.altitudes)}")
            col = (round(x / self.spacing), round(y / self.spacing))
            if col in columns:
                invalid_option("start_positions", p, "distinct (x, y) columns: two UAVs cannot share a column")
            columns.add(col)


#: The default map of every entry point that builds an env (``make_env``, ``make_vec_env``, the
#: gymnasium ids, ``sb3-coma train``, the studies): ``IppConfig``'s own, the paper's Env3. Defined
#: here, beside the options, so that reading it imports neither Stable-Baselines3 nor torch.
DEFAULT_MAP: str = IppConfig.map_name


# ------------------------------------------------ the same rules on the command line
#: The largest seed: numpy's and Stable-Baselines3's seeding (``np.random.seed``) take 0 .. 2**32 - 1.
SEED_MAX = 2**32 - 1


def integer_type(
    least: int | None, most: int | None = None, sentinels: Mapping[int, str] | None = None
) -> Callable[[str], int]:
    """An argparse ``type=`` for an integer option: a whole number from ``least`` (``None``: any) to
    ``most`` (``None``: no bound), or one of ``sentinels`` (value -> what it means, as the option's
    help documents it). Anything else is an ``argparse.ArgumentTypeError`` naming the value and what
    is allowed, which ``sb3-coma`` prints as one line, ``argument --seed: must be ..., got -1``."""
    named = dict(sentinels or {})
    if least is None:
        rule = "an integer"
    elif most is None:
        rule = f"an integer >= {least}"
    else:
        rule = f"an integer from {least} to {most}"
    allowed = " or ".join([*(f"{value} ({meaning})" for value, meaning in named.items()), rule])

    def integer(text: str) -> int:
        try:
            value = int(text.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        if value not in named and ((least is not None and value < least) or (most is not None and value > most)):
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {value}")
        return value

    integer.__name__ = "integer"  # argparse's own messages name the type by it
    return integer


#: ``type=`` of a count: an integer >= 1 (copies, missions, UAVs, decisions, threads, epochs ...).
count_value = integer_type(1)
#: ``type=`` of a count that may be none: 0 (none: the step is skipped) or an integer >= 1.
count_or_none_value = integer_type(1, sentinels={0: "none"})
#: ``type=`` of a seed: an integer from 0 to :data:`SEED_MAX`.
seed_value = integer_type(0, SEED_MAX)
