"""``sb3_coma.training.train``: the public name of a training run, kept where users import it.

The code lives in the application layer, :mod:`sb3_coma.app.training`.
"""

from sb3_coma.app.training import train

__all__ = ["train"]
