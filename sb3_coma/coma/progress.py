"""A progress bar that counts joint steps, matching COMA's ``num_timesteps``.

SB3's ``ProgressBarCallback`` advances by ``num_envs`` per step, i.e. by agent steps here; with
``N`` agents per env copy the bar would run ``N`` times too fast.
"""

from __future__ import annotations

from stable_baselines3.common.callbacks import ProgressBarCallback


class JointStepProgressBar(ProgressBarCallback):
    """Advances by the number of env copies (joint steps) per vec-env step."""

    def _on_step(self) -> bool:
        self.pbar.update(getattr(self.model, "n_copies", self.training_env.num_envs))
        return True
