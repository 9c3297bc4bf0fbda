"""Reproduce the paper's results and the project's own checks: ``sb3-coma reproduce``.

``reproduce()`` evaluates the shipped COMA models (or, with ``train=True``, models retrained
through ``zoo_configs/coma.yml``), every other shipped model of each map, and the baselines (AG with
the map's validated weighting, AG with look-ahead 2 and 3, lawnmower, random; IPPO / MAPPO rows
when such models are shipped) in named steps (``run.STEPS``), writing into ``out``:

* ``table.md`` / ``table.csv`` -- Table I, the **paper protocol** (split "paper", 10 seeded trials):
  F1 and entropy of the global map at 33/67/100 % of the budget, mean +- std;
  ``team_table.md`` / ``.csv`` the team metrics (each UAV's own map) the same way;
  ``paper_verdicts.md`` / ``.csv`` the paired verdicts; ``per_step.csv``, ``planning_time.csv``
* ``acceptance.md`` -- does COMA beat every baseline on F1 *and* entropy (paired tests), per env
* ``ablation.md`` / ``.csv`` -- the env3 SenDFuse x CBAM ablation at three noise levels
* ``paired.md`` -- COMA vs AG and the full model vs each ablation arm on more paper-split missions
* ``unseen_*.md`` / ``.csv`` -- the **unseen protocol** (50 missions on split "test", random
  starts): tables, team tables, verdicts
* ``generalisation.md`` -- each env's model on the other maps and a fresh env1 star seed
* ``noise_sweep.md`` / ``.csv`` -- AG and each ablation arm over sigma, a_low, drop probability
  and both decoders (``sb3_coma.experiments.noise_sweep``)
* ``latency.md`` -- the deployment cost per UAV decision (``sb3_coma.experiments.costs``)
* ``summary.json`` -- every number above; ``figures/``; ``RESULTS.md`` (``sb3_coma.experiments.report``),
  with ``docs=...`` also written there (figures next to it)

``out`` is written as one staged output (``sb3_coma.app.outputs.staged_output``): everything goes
into ``<out>.partial-<pid>`` and replaces ``out`` only when the run is complete, so an interrupted
run (SIGKILL, SIGTERM, an error) leaves the previous results as they were. The ``docs`` copy is
written at the end of the run, just before that swap.

Every "A beats B" in the report is a paired test on shared missions (``sb3_coma.stats.paired``);
everything in it is measured by the run that writes it; nothing is copied in.

The package is one module per step or pair of steps (``models``: 1, ``protocol_steps``: 2 and 5,
``ablation_steps``: 3 and 4, ``generalisation``: 6 and 7, ``sweep_costs``: 8 and 9, ``shipping``:
10, ``writing``: 11 and 12); each step takes the options and the earlier results it needs and
returns its own frozen result (``results``), and ``run.reproduce`` composes them in order. The
names below are those imported from ``sb3_coma.experiments.reproduce`` elsewhere (the CLI,
``ship_models``, the tests).
"""

from sb3_coma.experiments.reproduce.acceptance import ablation_acceptance, acceptance
from sb3_coma.experiments.reproduce.generalisation import untrained_prior
from sb3_coma.experiments.reproduce.options import ABLATION_ARMS, QUICK_TIMESTEPS, UNSEEN_MISSIONS
from sb3_coma.experiments.reproduce.run import reproduce
from sb3_coma.experiments.reproduce.shipping import _manifest_name
from sb3_coma.experiments.reproduce.sweep_costs import _time_fusion
from sb3_coma.experiments.reproduce.training import _train_model, curve_from_metrics, shipped_seed, shipped_timesteps
from sb3_coma.experiments.reproduce.writing import README_MARKERS, seed_spread_rows, write_readme_block

__all__ = [
    "ABLATION_ARMS",
    "QUICK_TIMESTEPS",
    "README_MARKERS",
    "UNSEEN_MISSIONS",
    "_manifest_name",
    "_time_fusion",
    "_train_model",
    "ablation_acceptance",
    "acceptance",
    "curve_from_metrics",
    "reproduce",
    "seed_spread_rows",
    "shipped_seed",
    "shipped_timesteps",
    "untrained_prior",
    "write_readme_block",
]
