"""sb3-coma: COMA (counterfactual multi-agent policy gradients) for Stable-Baselines3, with a
multi-UAV informative path planning world (SenDFuse, CBAM) as its first user.

The library: ``COMA`` and its policies for any env (``MlpPolicy``, ``CnnPolicy``,
``MultiInputPolicy``), ``make_marl_vec_env`` (any PettingZoo ``ParallelEnv`` -> the multi-agent
VecEnv COMA reads), the features extractors, SenDFuse and ``training_options`` (the env options a
saved model was trained with), the UAV world's policies (``CBAMPolicy``, ``UavCnnPolicy``) and two
front doors of the application, ``evaluate`` (a model, a shipped name, a path or a baseline on
seeded missions) and ``load_pretrained`` (a shipped trained model).

Every name is served lazily (PEP 562), on first use: ``import sb3_coma`` loads neither the UAV
world nor rl_zoo3 nor the application, and not even torch, because importing any submodule
(``sb3_coma.cli`` for ``sb3-coma --help``, ``sb3_coma.common.shipped``) runs this file first;
``from sb3_coma import COMA`` loads the algorithm then.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
from collections.abc import Sequence
from functools import partial
from types import ModuleType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names as the type checker sees them; at run time __getattr__ serves them
    from sb3_coma.coma import COMA, CnnPolicy, COMAPolicy, MlpPolicy, MultiInputPolicy
    from sb3_coma.common.checkpoints import training_options
    from sb3_coma.common.extractors import CBAMExtractor, CnnExtractor
    from sb3_coma.common.marl_vec_env import make_marl_vec_env
    from sb3_coma.sendfuse import SenDFuseNet

__version__ = "0.21.0"

#: Names served lazily (``name -> module``): the library, the application's front doors and the
#: UAV policies. The application's modules are named here as data, never imported by a statement.
_LAZY = {
    "COMA": "sb3_coma.coma",
    "COMAPolicy": "sb3_coma.coma",
    "CnnPolicy": "sb3_coma.coma",
    "MlpPolicy": "sb3_coma.coma",
    "MultiInputPolicy": "sb3_coma.coma",
    "training_options": "sb3_coma.common.checkpoints",
    "CBAMExtractor": "sb3_coma.common.extractors",
    "CnnExtractor": "sb3_coma.common.extractors",
    "make_marl_vec_env": "sb3_coma.common.marl_vec_env",
    "SenDFuseNet": "sb3_coma.sendfuse",
    "evaluate": "sb3_coma.app.evaluation",
    "load_pretrained": "sb3_coma.app.pretrained",
    "CBAMPolicy": "sb3_coma.uav.policies",
    "UavCnnPolicy": "sb3_coma.uav.policies",
}


#: Modules that moved, old dotted name -> new. IPPO / MAPPO zips saved while they lived in
#: ``sb3_coma.common`` name their policy classes there (``PPO.load`` unpickles them by name), and
#: ``sb3_coma.common.marl_baselines.make_ippo`` was a public name: an old name imports as a module
#: that serves the new module's names (the same functions and classes).
_MOVED = {
    "sb3_coma.common.marl_baselines": "sb3_coma.mappo.mappo",
    "sb3_coma.common.central_value": "sb3_coma.mappo.central_value",
}


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Serves each old name of :data:`_MOVED` as a module whose every name is the new module's
    (PEP 562 ``__getattr__``): the same functions and classes, imported on first use."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        return importlib.util.spec_from_loader(fullname, self) if fullname in _MOVED else None

    def exec_module(self, module: ModuleType) -> None:
        home = importlib.import_module(_MOVED[module.__name__])
        module.__doc__ = f"Moved to :mod:`{home.__name__}`; the old name serves saved models and old imports."
        vars(module).update(__all__=list(getattr(home, "__all__", ())), __getattr__=partial(getattr, home))


if not any(isinstance(finder, _MovedModules) for finder in sys.meta_path):
    sys.meta_path.append(_MovedModules())


def __getattr__(name: str) -> Any:
    """PEP 562: each name imports its module on first use (the library torch, the front doors the
    application, the UAV policies the world), so that the command line starts without them."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # later look-ups are plain attribute reads
        return value
    raise AttributeError(f"module 'sb3_coma' has no attribute {name!r}")


def __dir__() -> list[str]:
    """``dir(sb3_coma)`` lists the lazy names too, as it did when they were imported eagerly."""
    return sorted({*globals(), *_LAZY})


__all__ = [
    "COMA",
    "CBAMExtractor",
    "CBAMPolicy",
    "COMAPolicy",
    "CnnExtractor",
    "CnnPolicy",
    "MlpPolicy",
    "MultiInputPolicy",
    "SenDFuseNet",
    "UavCnnPolicy",
    "__version__",
    "evaluate",
    "load_pretrained",
    "make_marl_vec_env",
    "training_options",
]
