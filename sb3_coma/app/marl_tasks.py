"""Third-party cooperative tasks by env id: what ``python -m sb3_coma.zoo train --env ID``,
``sb3-coma train --env ID`` and the learner benchmark build.

An env id is resolved once, here, into a :class:`MarlTask`:

* a name of :data:`NAMED_TASKS` (the learner benchmark's tasks: ``simple_spread``,
  ``simple_reference``, the LBF and RWARE gymnasium ids), each with the options the benchmark and
  ``zoo_configs/marl/<algo>.yml`` are written for;
* ``package.module:factory``, a user's own callable returning a fresh PettingZoo ``ParallelEnv``
  (the way gymnasium names an entry point): any cooperative env trains without registering it.

Factories are module-level functions (or ``functools.partial`` of them) so a worker process can
rebuild the env from the id alone. A factory takes keyword options (a config entry's
``env_kwargs``, rl-zoo3's ``--env-kwargs``): a named task's options change its defaults
(``N``, ``max_cycles`` of MPE; gymnasium's ``make`` keywords of LBF and RWARE).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

from sb3_coma.app.config import TrainingError


@dataclass(frozen=True)
class MarlTask:
    """A cooperative PettingZoo task: its env id (config key, folder name) and its factory."""

    env_id: str
    maker: Callable[..., Any]

    def with_options(self, options: dict[str, Any]) -> Callable[[], Any]:
        """The factory of this task with ``options`` (``env_kwargs``) bound: picklable for workers."""
        return partial(self.maker, **options) if options else self.maker

    def agents(self, options: dict[str, Any]) -> int:
        """Agents of the task with ``options`` (one env is built and closed to read it); an option
        the factory refuses is one line naming ``options``."""
        try:
            env = self.with_options(options)()
        except TypeError as exc:
            raise TrainingError(f"{self.env_id}: env_kwargs {options} ({exc})") from None
        try:
            return len(env.possible_agents)
        finally:
            env.close()


def _simple_spread(**options: Any) -> Any:
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(**{"N": 3, "max_cycles": 25, "continuous_actions": False, **options})


def _simple_reference(**options: Any) -> Any:
    from mpe2 import simple_reference_v3

    return simple_reference_v3.parallel_env(**{"max_cycles": 25, "continuous_actions": False, **options})


def _gymnasium_task(env_id: str, registers: str, **options: Any) -> Any:
    """A gymnasium multi-agent env (Tuple spaces) as a ParallelEnv; ``registers`` is the module
    whose import registers ``env_id`` (``lbforaging``, ``rware``)."""
    import gymnasium

    from sb3_coma.common.gymnasium_marl import GymnasiumMultiAgentToParallel

    importlib.import_module(registers)
    return GymnasiumMultiAgentToParallel(gymnasium.make(env_id, disable_env_checker=True, **options))


#: The named tasks (env id -> factory); ``zoo_configs/marl/<algo>.yml`` has an entry for each.
NAMED_TASKS: dict[str, Callable[..., Any]] = {
    "simple_spread": _simple_spread,
    "simple_reference": _simple_reference,
    "Foraging-5x5-2p-1f-coop-v3": partial(_gymnasium_task, "Foraging-5x5-2p-1f-coop-v3", "lbforaging"),
    "Foraging-8x8-2p-2f-coop-v3": partial(_gymnasium_task, "Foraging-8x8-2p-2f-coop-v3", "lbforaging"),
    "rware-tiny-2ag-v2": partial(_gymnasium_task, "rware-tiny-2ag-v2", "rware"),
}

#: Joint steps per run on the named tasks: the learner benchmark's budget, equal for every learner,
#: and the zoo's ``n_timesteps`` for an entry that does not give one.
BENCHMARK_JOINT_STEPS: dict[str, int] = {
    "simple_spread": 300_000,
    "simple_reference": 300_000,
    "Foraging-5x5-2p-1f-coop-v3": 200_000,
    "Foraging-8x8-2p-2f-coop-v3": 300_000,
    "rware-tiny-2ag-v2": 500_000,
}


def is_marl_task_id(env_id: str) -> bool:
    """Whether ``env_id`` names a third-party task (a named one or ``module:factory``), by its form
    alone: nothing is imported."""
    return env_id in NAMED_TASKS or (":" in env_id and all(env_id.partition(":")[::2]))


def resolve_task(env_id: str) -> MarlTask:
    """The task of ``env_id``; a one-line :class:`TrainingError` naming the id otherwise."""
    if env_id in NAMED_TASKS:
        return MarlTask(env_id, NAMED_TASKS[env_id])
    module_name, _, attribute = env_id.partition(":")
    if not (module_name and attribute):
        raise TrainingError(
            f"unknown task {env_id!r}: use one of {', '.join(NAMED_TASKS)} or 'package.module:factory' "
            "(a callable returning a PettingZoo ParallelEnv)"
        )
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise TrainingError(f"task {env_id!r}: cannot import {module_name!r} ({exc})") from None
    factory = getattr(module, attribute, None)
    if not callable(factory):
        raise TrainingError(f"task {env_id!r}: {module_name} has no callable {attribute!r}")
    return MarlTask(env_id, factory)
