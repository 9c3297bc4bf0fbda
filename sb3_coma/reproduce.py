"""Reproduce the paper's results: Table I, generalisation, deployment latency, training wall-clock.

``reproduce()`` (``sb3-coma reproduce``) evaluates the shipped COMA models (or, with
``train=True``, models retrained through ``zoo_configs/coma.yml``) and the baselines (AG,
lawnmower, random) on env1-env3 under the same seeded missions, and writes into ``out``:

* ``table.md`` / ``table.csv`` -- Table I: F1 and entropy at 33/67/100 % of the budget, mean +- std
* ``per_step.csv``, ``planning_time.csv``
* ``acceptance.md`` -- at 100 %: does COMA beat every baseline on F1 *and* entropy, per env
* ``generalisation.md`` / ``.csv`` -- each env's model on the other maps and a fresh env1 star seed
* ``latency.md`` -- actor + fusion time per UAV decision vs AG
* ``paired.md`` -- the paired check: COMA vs AG and the full model vs each ablation arm on the
  same, more numerous missions (``wide_trials``, default 50), differences with standard errors
* ``summary.json`` -- every number above
* ``figures/`` -- metric curves per env, training reward per env
* ``RESULTS.md`` -- the report; with ``docs=...`` it is also written there (figures next to it)

Everything in the report is measured by the run that writes it; nothing is copied in.
"""
from __future__ import annotations

import json
import platform
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

DEFAULT_ENVS: tuple[str, ...] = ("env1", "env2", "env3")
BASELINES: tuple[str, ...] = ("ag", "lawnmower", "random")
#: map seed of the "fresh" env1 star layout used for generalisation (env1's default map_seed is 0)
FRESH_ENV1_SEED = 7
#: tiny training used by ``quick=True`` together with ``train=True`` (joint steps and overrides)
QUICK_TIMESTEPS = 32
QUICK_OVERRIDES = {"n_envs": 2, "n_steps": 8, "batch_size": 16, "n_critic_epochs": 1}
#: evaluation seed base; training seed of the shipped models
TRAIN_SEED = 0
#: zoo-config variant of each shipped SenDFuse model: env2's prior starts at AG's greedy choice,
#: the start that scored best on env2's validation missions (sb3_coma/pretrained/MODELS.md)
SHIPPED_VARIANTS = {"env1": "fast", "env2": "fast-greedy", "env3": "fast"}
#: the shipped models are the best of the run's checkpoints on the SAME 20 validation missions
#: (env seeds 1000..1019, never the test seeds), scored every 1024 joint steps (``best_model.zip``)
TRAIN_EVAL_FREQ = 1024
TRAIN_EVAL_MISSIONS = 20
#: the map of the paper's ablation and the shipped models of its three other arms (the fourth,
#: SenDFuse + CBAM, is the env3 model itself)
ABLATION_ENV = "env3"
ABLATION_ARMS: dict[tuple[str, str], str] = {
    ("sendfuse", "cnn"): "env3-sendfuse-cnn",
    ("mean", "cbam"): "env3-mean-cbam",
    ("mean", "cnn"): "env3-mean-cnn",
}
#: the arm every other arm is compared with, and the noise level of that comparison
ABLATION_FULL = ("sendfuse", "cbam")
ABLATION_CHECK_NOISE = "loud"
#: Missions of the paired check that backs Table I's and the ablation's verdicts (sb3_coma.paired).
WIDE_TRIALS = 50


@dataclass
class ModelSource:
    env: str
    model: Any
    fusion: str
    source: str                      # "shipped" or the run folder
    command: str
    train_wall_s: float | None
    timesteps: int | None
    training_curve: list[float] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)
    deterministic: bool = True       # argmax actions (True) or seeded draws from the policy (False)


def sendfuse_available() -> bool:
    """Whether ``fusion="sendfuse"`` can be built (its pre-trained weights exist)."""
    import envs

    try:
        envs.make_vec_env("env1", fusion="sendfuse").close()
        return True
    except Exception:  # noqa: BLE001 - any failure means: not usable here
        return False


def _variant_for(env: str, fusion: str) -> str:
    """The zoo config variant with the shipped models' settings for an env and a fusion."""
    return SHIPPED_VARIANTS.get(env, "fast") if fusion == "sendfuse" else "fast-mean"


def train_command(env: str, fusion: str, seed: int = TRAIN_SEED, validate: bool = True) -> str:
    """The command that retrains a shipped model (with ``validate``, its ``best_model.zip`` is the model)."""
    command = f"sb3-coma train --env {env} --variant {_variant_for(env, fusion)} --seed {seed}"
    return command + (f" --eval-freq {TRAIN_EVAL_FREQ} --eval-missions {TRAIN_EVAL_MISSIONS}" if validate else "")


def _curve_from_metrics(path: Path) -> list[float]:
    import csv

    if not path.is_file():
        return []
    with path.open() as fh:
        return [round(float(row["reward"]), 4) for row in csv.DictReader(fh)]


def shipped_seed(env: str) -> int:
    """The training seed of the shipped model of ``env`` (the seed whose run won on the validation
    missions, MODELS.md), so ``--train`` retrains that very model; ``TRAIN_SEED`` without one."""
    from sb3_coma.pretrained import model_info

    try:
        return int(model_info(env).get("seed", TRAIN_SEED))
    except ValueError:
        return TRAIN_SEED


def shipped_timesteps(env: str) -> int | None:
    """The joint steps the shipped model of ``env`` was trained for when its command sets them
    (``--timesteps``, recorded as ``train_timesteps``); ``None``: the config's ``n_timesteps``."""
    from sb3_coma.pretrained import model_info

    try:
        value = model_info(env).get("train_timesteps")
    except ValueError:
        return None
    return None if value is None else int(value)


def _train_model(env: str, fusion: str, out: Path, quick: bool, timesteps: int | None, log: Callable[[str], None],
                 deterministic: bool = True) -> ModelSource:
    from sb3_coma import COMA
    from sb3_coma.training import train

    overrides: dict[str, Any] = dict(QUICK_OVERRIDES) if quick else {}
    total = QUICK_TIMESTEPS if quick else (timesteps or shipped_timesteps(env))
    variant = _variant_for(env, fusion)
    seed = shipped_seed(env)
    run_dir = out / "runs" / env
    if run_dir.exists():
        shutil.rmtree(run_dir)
    log(f"training COMA on {env} (fusion {fusion}{', quick' if quick else ''}) ...")
    tic = time.perf_counter()
    _, run_path = train(env=env, variant=variant, seed=seed, total_timesteps=total, run_dir=run_dir,
                        overrides=overrides or None, progress_bar=False, verbose=0, handle_signals=False,
                        save_freq=10 ** 9, eval_freq=0 if quick else TRAIN_EVAL_FREQ,
                        eval_missions=TRAIN_EVAL_MISSIONS)
    wall = time.perf_counter() - tic
    model = COMA.load(str(_chosen_model(Path(run_path))), env=None, device="cpu")
    command = train_command(env, fusion, seed, validate=not quick) + (f" --timesteps {total}" if total else "")
    if overrides:
        command += "".join(f" --set {k}={v}" for k, v in overrides.items())
    log(f"  trained {env} in {wall:.1f} s -> {run_path}")
    return ModelSource(env, model, fusion, str(run_path), command, wall, int(model.num_timesteps),
                       _curve_from_metrics(Path(run_path) / "metrics.csv"), deterministic=deterministic)


def _chosen_model(run_path: Path) -> Path:
    """The run's model that reproduce uses and ships: the best checkpoint on the validation
    missions when the run evaluated, else the final one."""
    best = run_path / "best_model.zip"
    return best if best.is_file() else run_path / "model.zip"


def _shipped_model(env: str) -> ModelSource:
    from sb3_coma.pretrained import load_pretrained

    model = load_pretrained(env)
    info = model.pretrained_info
    return ModelSource(env, model, info.get("fusion", "sendfuse"), "shipped", info.get("command", ""),
                       info.get("train_wall_s"), info.get("timesteps"), list(info.get("training_curve", [])), info,
                       bool(info.get("deterministic", True)))


# ---------------------------------------------------------------------------------------------
# measurements
# ---------------------------------------------------------------------------------------------
def _evaluate_model(src: ModelSource, env: str, trials: int, seed: int, noise: str, label: str, **extra: Any) -> Any:
    """``evaluate`` a COMA model; sampled actions come from torch's generator, seeded here with ``seed``."""
    import torch as th

    from sb3_coma import evaluation as ev

    th.manual_seed(seed)
    return ev.evaluate(src.model, env=env, n_trials=trials, seed=seed, fusion=src.fusion, label=label,
                       deterministic=src.deterministic, noise=noise, **extra)


def untrained_prior(model: Any) -> Any:
    """The policy a gain-prior model starts from: its prior weights at their initial value and the
    network's contribution removed (output layer zeroed; at initialisation it is ~0.01 of the
    prior). ``None`` for a model without a gain prior. Evaluated with argmax actions, this is the
    greedy planner on the untrained mix of the two information gains, so comparing it with the
    trained model shows what COMA's training adds."""
    import copy

    import torch as th

    actor = model.policy.actor
    if getattr(actor, "prior_theta", None) is None:
        return None
    policy = copy.deepcopy(model.policy)
    with th.no_grad():
        policy.actor.head.weight.zero_()
        policy.actor.head.bias.zero_()
        policy.actor.prior_theta.copy_(th.tensor(policy.gain_prior_init) / policy.gain_prior_speed)
    return policy


def ablation_models(full_model: Any, say: Callable[[str], None] = print) -> dict[tuple[str, str], Any]:
    """The four ablation arms: ``full_model`` (the env3 model in use) plus the shipped models of
    the other three arms; an arm whose shipped model cannot be loaded is left out, with a message."""
    from sb3_coma.pretrained import PretrainedError, load_pretrained

    models: dict[tuple[str, str], Any] = {ABLATION_FULL: full_model}
    for arm, name in ABLATION_ARMS.items():
        try:
            models[arm] = load_pretrained(name)
        except PretrainedError as exc:
            say(f"ablation: leaving out {arm[0]}_{arm[1]}: {exc}")
    return models


def ablation_acceptance(result: Any, noise: str = ABLATION_CHECK_NOISE) -> dict[str, Any]:
    """Is the full model's entropy at 100 % of the budget under ``noise`` at most every other
    arm's? Returns the entropies by arm label and the verdict (``None`` when an arm is missing)."""
    from sb3_coma.ablation import LABELS

    full = LABELS[ABLATION_FULL]
    entropy = {label: float(r.mean_std("entropy", 1.0)[0]) for (label, n), r in result.results.items() if n == noise}
    others = {k: v for k, v in entropy.items() if k != full}
    met = None if full not in entropy or len(others) < len(LABELS) - 1 else all(entropy[full] <= v for v in others.values())
    return {"noise": noise, "full": full, "entropy": entropy, "met": met}


def _final(result: Any) -> dict[str, float]:
    f1, f1s = result.mean_std("f1", 1.0)
    en, ens = result.mean_std("entropy", 1.0)
    return {"f1": f1, "f1_std": f1s, "entropy": en, "entropy_std": ens}


def acceptance(results: Sequence[Any], model_label: str = "coma") -> dict[str, dict[str, Any]]:
    """Per env: COMA's 100 % F1/entropy, the best baseline on each, and whether COMA beats all."""
    out: dict[str, dict[str, Any]] = {}
    for env in dict.fromkeys(r.env for r in results):
        group = {r.method: _final(r) for r in results if r.env == env}
        if model_label not in group:
            continue
        mine = group.pop(model_label)
        best_f1 = max(group.items(), key=lambda kv: kv[1]["f1"]) if group else None
        best_en = min(group.items(), key=lambda kv: kv[1]["entropy"]) if group else None
        beats_f1 = all(mine["f1"] > v["f1"] for v in group.values())
        beats_en = all(mine["entropy"] < v["entropy"] for v in group.values())
        out[env] = {"coma": mine, "best_f1_baseline": best_f1[0] if best_f1 else None,
                    "best_f1": best_f1[1]["f1"] if best_f1 else None,
                    "best_entropy_baseline": best_en[0] if best_en else None,
                    "best_entropy": best_en[1]["entropy"] if best_en else None,
                    "beats_f1": beats_f1, "beats_entropy": beats_en, "beats_all": beats_f1 and beats_en}
    return out


def _time_fusion(fusion: str, n_agents: int, reps: int = 200) -> float | None:
    """ms per UAV decision of fusing the N received maps of one UAV (batch of one)."""
    from envs import fusion as fz

    rng = np.random.default_rng(0)
    received = rng.random((1, n_agents, 44, 44), dtype=np.float32)
    valid = np.ones((1, n_agents), dtype=bool)
    if fusion == "mean":
        fn = lambda: fz.mean_fusion(received, valid)  # noqa: E731
    else:
        try:
            import torch as th

            from sb3_coma.sendfuse.weights import default_weights_path, load_weights

            net = load_weights(default_weights_path(received.shape[-1]))
            x, v = th.as_tensor(received), th.as_tensor(valid)

            def fn() -> Any:
                with th.inference_mode():
                    return net.fuse(x, v)
        except Exception:  # noqa: BLE001 - weights missing or unreadable: report n/a, not a crash
            return None
    fn()
    tic = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - tic) * 1e3 / reps


def _time_actor(model: Any, env: str, fusion: str, noise: str, reps: int = 100) -> float:
    """ms of one UAV's decision (batch of one observation), as on board."""
    import envs

    venv = envs.make_vec_env(env, n_envs=1, fusion=fusion, seed=0, noise=noise)
    obs = venv.reset()
    venv.close()
    one = {k: v[:1] for k, v in obs.items()}
    model.predict(one, deterministic=True)
    tic = time.perf_counter()
    for _ in range(reps):
        model.predict(one, deterministic=True)
    return (time.perf_counter() - tic) * 1e3 / reps


# ---------------------------------------------------------------------------------------------
# the run
# ---------------------------------------------------------------------------------------------
def reproduce(out: str | Path = "results", env_names: Sequence[str] = DEFAULT_ENVS, trials: int = 10, seed: int = 0,
              noise: str = "moderate", train: bool = False, quick: bool = False, timesteps: int | None = None,
              fusion: str | None = None, docs: str | Path | None = None, plots: bool = True, ship: bool = False,
              generalisation: bool = True, deterministic: bool | None = None, record: bool = False,
              ablation: bool = True, wide_trials: int = WIDE_TRIALS,
              log: Callable[[str], None] | None = print) -> dict[str, Any]:
    """Run the reproduction (see module docstring) and return the summary dict.

    :param train: retrain each env's model through the zoo config instead of loading the shipped one
    :param quick: smoke test: 2 trials (unless ``trials`` is smaller) and, with ``train``, a tiny training
    :param fusion: fusion of retrained models (default: the shipped model's, else sendfuse when its
        weights exist, else mean)
    :param docs: also write ``RESULTS.md`` at this path and its figures in ``<docs dir>/figures``
    :param deterministic: argmax actions or seeded draws from the policy (default: the shipped
        model's ``deterministic`` entry, True for retrained models without one)
    :param record: write the measured Table I numbers of the shipped models into ``models.json``
        (``metrics``; checksums and files untouched)
    :param ship: with ``train``: copy the trained zips into ``sb3_coma/pretrained`` and update
        ``models.json`` (checksums, command, wall-clock, metrics)
    :param ablation: when env3 is among the envs, the paper's ablation on env3 at the three noise
        levels: the env3 model in use and the shipped models of the other three arms
    :param wide_trials: missions of the paired check (``sb3_coma.paired``): COMA vs AG per env and
        the full model vs every ablation arm under loud noise, each pair on the same missions, so
        the verdicts are tested against mission-to-mission noise (0: skip; ``quick``: ``trials``)
    """
    from sb3_coma import evaluation as ev

    say = log or (lambda _m: None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if quick:
        trials = min(trials, 2)
        wide_trials = min(wide_trials, trials)
    if isinstance(wide_trials, bool) or not isinstance(wide_trials, int) or wide_trials < 0 or wide_trials == 1:
        raise ValueError(f"wide_trials must be 0 (skip) or an integer >= 2, got {wide_trials!r}")
    if ship and (not train or quick):
        raise ValueError("ship=True needs train=True and quick=False")
    env_names = list(env_names)

    # ---- models
    sources: dict[str, ModelSource] = {}
    for env in env_names:
        if train:
            fz = fusion
            if fz is None:
                try:
                    from sb3_coma.pretrained import model_info

                    fz = model_info(env).get("fusion")
                except ValueError:
                    fz = None
            if fz == "sendfuse" or fz is None:
                fz = "sendfuse" if sendfuse_available() else "mean"
            det = deterministic
            if det is None:
                try:
                    from sb3_coma.pretrained import model_info

                    det = bool(model_info(env).get("deterministic", True))
                except ValueError:
                    det = True
            sources[env] = _train_model(env, fz, out, quick, timesteps, say, det)
        else:
            sources[env] = _shipped_model(env)
            if deterministic is not None:
                sources[env].deterministic = deterministic

    # ---- Table I
    results = []
    for env in env_names:
        src = sources[env]
        say(f"evaluating coma on {env} ({trials} trials, noise {noise}, fusion {src.fusion}) ...")
        results.append(_evaluate_model(src, env, trials, seed, noise, "coma"))
        for name in BASELINES:
            say(f"evaluating {name} on {env} ...")
            results.append(ev.evaluate(name, env=env, n_trials=trials, seed=seed, noise=noise))
    rows = ev.rows_for(results)
    ev.write_table_csv(rows, out / "table.csv")
    ev.write_per_step_csv(rows, out / "per_step.csv")
    ev.write_planning_time_csv(rows, out / "planning_time.csv")
    table = ev.table_markdown(rows)
    (out / "table.md").write_text(table)
    accept = acceptance(results)
    (out / "acceptance.md").write_text(_acceptance_markdown(accept))

    # ---- generalisation
    gen: list[dict[str, Any]] = []
    if generalisation:
        # quick: only the fresh env1 layout (the cross-map runs are the same code path)
        targets = ([] if quick else [(e, {}) for e in env_names]) + \
            [(f"env1 (map_seed={FRESH_ENV1_SEED})", {"map_seed": FRESH_ENV1_SEED})]
        fresh_label = targets[-1][0]
        for env, src in sources.items():
            for target, extra in targets:
                if target == env:
                    continue  # in Table I
                base_env = "env1" if extra else target
                say(f"generalisation: {env} model on {target} ...")
                r = _evaluate_model(src, base_env, trials, seed, noise, f"coma[{env}]", **extra)
                gen.append({"model": env, "target": target, **_final(r)})
        for name in BASELINES:
            r = ev.evaluate(name, env="env1", n_trials=trials, seed=seed, noise=noise, map_seed=FRESH_ENV1_SEED)
            gen.append({"model": name, "target": fresh_label, **_final(r)})
    for r in results:  # own-map numbers for reference
        if r.method == "coma":
            gen.append({"model": r.env, "target": r.env, **_final(r)})
    (out / "generalisation.md").write_text(_generalisation_markdown(gen, env_names, results))

    # ---- what training adds over the untrained gain prior
    prior_rows: list[dict[str, Any]] = []
    for env, src in sources.items():
        policy = untrained_prior(src.model)
        if policy is None:
            continue
        say(f"evaluating the untrained gain prior of the {env} model ...")
        r = ev.evaluate(policy, env=env, n_trials=trials, seed=seed, fusion=src.fusion, deterministic=True,
                        noise=noise, label="prior")
        trained = next(x for x in results if x.env == env and x.method == "coma")
        prior_rows.append({"env": env, "prior": _final(r), "trained": _final(trained),
                           "weights_start": [float(w) for w in policy.gain_prior_init],
                           "weights_trained": [round(float(w), 3) for w in src.model.policy.actor.prior_weights.detach()]})

    # ---- ablation (env3: SenDFuse x CBAM at three noise levels)
    ablation_summary: dict[str, Any] | None = None
    ablation_table = ""
    ablation_result = None
    arms: dict[tuple[str, str], Any] = {}
    if ablation and ABLATION_ENV in sources:
        from sb3_coma import ablation as ab

        arms = ablation_models(sources[ABLATION_ENV].model, say)
        ablation_result = ab.run_ablation(arms, env=ABLATION_ENV, n_trials=trials, seed=seed, log=say)
        ablation_rows = ablation_result.rows()
        ev.write_table_csv(ablation_rows, out / "ablation.csv", group_title="noise")
        ablation_table = ablation_result.markdown()
        (out / "ablation.md").write_text(ablation_table)
        ablation_summary = ablation_acceptance(ablation_result)
        arms = {v: m for v, m in arms.items() if ab.LABELS[v] not in ablation_result.skipped}  # flown above

    # ---- the paired check on more missions
    wide: dict[str, Any] | None = None
    wide_table = ""
    if wide_trials:
        wide, wide_table = _paired_check(sources, arms, wide_trials, seed, noise, say)
        (out / "paired.md").write_text(wide_table)

    # ---- latency
    latency = []
    for env, src in sources.items():
        ag = next(r for r in results if r.env == env and r.method == "ag")
        coma = next(r for r in results if r.env == env and r.method == "coma")
        n_agents = coma.n_agents
        latency.append({"env": env, "fusion": src.fusion,
                        "actor_ms_batch1": _time_actor(src.model, env, src.fusion, noise, reps=10 if quick else 100),
                        "actor_ms_batched": float(coma.planning_time_ms.mean()),
                        "fusion_ms": _time_fusion(src.fusion, n_agents, reps=20 if quick else 200),
                        "ag_ms": float(ag.planning_time_ms.mean())})
    (out / "latency.md").write_text(_latency_markdown(latency))

    summary = {
        "command": " ".join(["sb3-coma reproduce"] + (["--train"] if train else []) + (["--quick"] if quick else [])
                            + (["--record"] if record and not train else [])),
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "python": sys.version.split()[0],
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "trials": trials, "seed": seed, "noise": noise, "envs": env_names,
        "models": {env: {"source": s.source, "fusion": s.fusion, "command": s.command, "train_wall_s": s.train_wall_s,
                         "timesteps": s.timesteps, "deterministic": s.deterministic} for env, s in sources.items()},
        "table": {f"{r.env}/{r.method}": r.summary() for r in results},
        "acceptance": accept, "generalisation": gen, "latency": latency, "untrained_prior": prior_rows,
        "ablation": ablation_summary, "paired": wide,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")

    # ---- figures
    figures: list[Path] = []
    if plots:
        from sb3_coma import plots as pl

        fig_dir = out / "figures"
        groups = {env: [r for r in results if r.env == env] for env in env_names}
        figures.append(pl.plot_metric_grid(groups, fig_dir / "table1_curves.png",
                                           title=f"F1 and entropy vs step, noise {noise}, {trials} trials"))
        curves = {f"{env}": pl.TrainingCurve(np.arange(1, len(s.training_curve) + 1), np.asarray(s.training_curve),
                                             s.source) for env, s in sources.items() if s.training_curve}
        if curves:
            figures.append(pl.plot_training_reward(curves, fig_dir / "training_reward.png"))
        if ablation_result is not None and ablation_result.results:
            figures.append(pl.plot_metric_grid(ablation_result.by_noise(), fig_dir / "ablation_curves.png",
                                               title=f"{ABLATION_ENV}: F1 and entropy vs step per noise level"))
            figures.append(pl.plot_ablation(dict(ablation_result.results), fig_dir / "ablation_bars.png",
                                            title=f"{ABLATION_ENV}: ablation at 100 % of the budget"))

    # ---- ship
    if ship:
        _ship(sources, results, say)
    elif record and not train:
        record_metrics(results, say)

    summary["ablation_table"] = ablation_table
    summary["paired_table"] = wide_table if wide else ""
    report = results_markdown(summary, table, figures, out)
    (out / "RESULTS.md").write_text(report)
    if docs is not None:
        docs = Path(docs)
        fig_docs = docs.parent / "figures"
        fig_docs.mkdir(parents=True, exist_ok=True)
        for f in figures:
            shutil.copyfile(f, fig_docs / f.name)
        docs.write_text(results_markdown(summary, table, [fig_docs / f.name for f in figures], docs.parent))
        say(f"wrote {docs}")
    say(_acceptance_markdown(accept))
    if ablation_summary is not None:
        say(_ablation_verdict(ablation_summary))
    say(f"wrote {out}/ (table.md, acceptance.md, generalisation.md, latency.md, summary.json, RESULTS.md"
        + (", ablation.md" if ablation_summary is not None else "") + (", paired.md" if wide else "") + ")")
    return summary


def _paired_check(sources: dict[str, ModelSource], arms: dict[tuple[str, str], Any], trials: int, seed: int,
                  noise: str, say: Callable[[str], None]) -> tuple[dict[str, Any], str]:
    """COMA vs AG per env (F1 and entropy) and the full model vs every other ablation arm in
    ``arms`` (the ablation's models; entropy under loud noise), each pair flown on the same
    ``trials`` missions. Returns the numbers (for summary.json) and their Markdown tables."""
    from sb3_coma import ablation as ab
    from sb3_coma import evaluation as ev
    from sb3_coma.paired import paired_difference, paired_markdown

    table1 = []
    for env, src in sources.items():
        say(f"paired check: coma vs ag on {env} ({trials} missions) ...")
        coma = _evaluate_model(src, env, trials, seed, noise, "coma")
        ag = ev.evaluate("ag", env=env, n_trials=trials, seed=seed, noise=noise)
        table1 += [(env, paired_difference(coma, ag, "f1")), (env, paired_difference(coma, ag, "entropy"))]
    runs = {}
    for variant, model in arms.items():
        label = ab.LABELS[variant]
        say(f"paired check: {label} on {ABLATION_ENV}, noise {ABLATION_CHECK_NOISE} ({trials} missions) ...")
        runs[label] = ev.evaluate(model, env=ABLATION_ENV, n_trials=trials, seed=seed, fusion=variant[0],
                                  label=label, noise=ABLATION_CHECK_NOISE)
    full = ab.LABELS[ABLATION_FULL]
    diffs = [paired_difference(runs[full], r, "entropy") for label, r in runs.items() if label != full and full in runs]
    met = all(d.diff <= 0 for d in diffs) if len(diffs) == len(ABLATION_ARMS) else None

    missions = f"{trials} missions (env seeds {seed}..{seed + trials - 1})"
    parts = [f"COMA vs AG on the same {missions} per env, noise `{noise}`:\n",
             paired_markdown([d for _, d in table1], [env for env, _ in table1])]
    if diffs:
        verdict = "at most" if met else "NOT at most"
        parts += [f"\nThe full model against each other ablation arm on the same {missions}, "
                  f"`{ABLATION_CHECK_NOISE}` noise: its mean entropy is {verdict} every other arm's "
                  f"(the verdict column says which differences exceed two standard errors).\n",
                  paired_markdown(diffs, [ABLATION_CHECK_NOISE] * len(diffs), first_title="noise")]
    numbers = {"trials": trials, "seed": seed, "noise": noise,
               "table1": [{"env": env, **d.as_dict()} for env, d in table1],
               "ablation": [d.as_dict() for d in diffs], "ablation_noise": ABLATION_CHECK_NOISE, "ablation_met": met}
    return numbers, "\n".join(parts)


def _metrics_entry(res: Any) -> dict[str, Any]:
    return {"metrics": {k: round(v, 4) for k, v in res.summary().items()},
            "metrics_note": f"measured by sb3-coma reproduce: {res.n_trials} trials, env seeds "
                            f"{res.seed}..{res.seed + res.n_trials - 1}, noise {res.env_options.get('noise')}, "
                            f"fusion {res.fusion}"}


def record_metrics(results: Sequence[Any], say: Callable[[str], None] = print) -> None:
    """Store the measured metrics of the shipped models in ``models.json``."""
    from sb3_coma import pretrained as pt

    manifest = pt.read_manifest()
    for res in results:
        if res.method == "coma" and res.env in manifest["models"]:
            manifest["models"][res.env].update(_metrics_entry(res))
    say(f"recorded metrics in {pt.write_manifest(manifest)}")


def _ship(sources: dict[str, ModelSource], results: Sequence[Any], say: Callable[[str], None]) -> None:
    from sb3_coma import pretrained as pt

    directory = pt.pretrained_dir()
    directory.mkdir(parents=True, exist_ok=True)
    try:
        manifest = pt.read_manifest()
    except pt.PretrainedError:
        manifest = {"format": 1, "models": {}}
    for env, src in sources.items():
        res = next(r for r in results if r.env == env and r.method == "coma")
        manifest["models"][env] = {
            **pt.save_for_shipping(src.model, f"coma_{env}.zip", directory),
            "env": env, "fusion": src.fusion, "variant": _variant_for(env, src.fusion), "seed": shipped_seed(env),
            "deterministic": src.deterministic,
            "timesteps": src.timesteps, "command": src.command, "train_wall_s": round(float(src.train_wall_s or 0), 1),
            **_metrics_entry(res),
            "training_curve": src.training_curve,
        }
        say(f"shipped {directory / manifest['models'][env]['file']}")
    pt.write_manifest(manifest)


# ---------------------------------------------------------------------------------------------
# markdown
# ---------------------------------------------------------------------------------------------
def _acceptance_markdown(accept: dict[str, dict[str, Any]]) -> str:
    lines = ["| Env | COMA F1 @100% | best baseline F1 | COMA entropy @100% | best baseline entropy | beats all on F1 | "
             "beats all on entropy |", "| --- | ---: | --- | ---: | --- | :---: | :---: |"]
    for env, a in accept.items():
        c = a["coma"]
        lines.append(f"| {env} | {c['f1']:.4f} ± {c['f1_std']:.4f} | {a['best_f1_baseline']} {a['best_f1']:.4f} | "
                     f"{c['entropy']:.4f} ± {c['entropy_std']:.4f} | {a['best_entropy_baseline']} {a['best_entropy']:.4f} | "
                     f"{'yes' if a['beats_f1'] else 'NO'} | {'yes' if a['beats_entropy'] else 'NO'} |")
    return "\n".join(lines) + "\n"


def _generalisation_markdown(gen: list[dict[str, Any]], env_names: Sequence[str], results: Sequence[Any]) -> str:
    lines = ["| model (trained on) | evaluated on | F1 @100% | entropy @100% |", "| --- | --- | ---: | ---: |"]
    for g in sorted(gen, key=lambda g: (g["model"] in BASELINES, g["model"], g["target"])):
        own = " (own map)" if g["model"] == g["target"] else ""
        lines.append(f"| {g['model']}{own} | {g['target']} | {g['f1']:.4f} ± {g['f1_std']:.4f} | "
                     f"{g['entropy']:.4f} ± {g['entropy_std']:.4f} |")
    return "\n".join(lines) + "\n"


def _prior_markdown(rows: list[dict[str, Any]]) -> str:
    lines = ["| Env | untrained prior F1 | trained F1 | untrained prior entropy | trained entropy | prior weights "
             "(class, plain): start -> trained |", "| --- | ---: | ---: | ---: | ---: | --- |"]
    for r in rows:
        p, t = r["prior"], r["trained"]
        lines.append(f"| {r['env']} | {p['f1']:.4f} ± {p['f1_std']:.4f} | {t['f1']:.4f} ± {t['f1_std']:.4f} | "
                     f"{p['entropy']:.4f} ± {p['entropy_std']:.4f} | {t['entropy']:.4f} ± {t['entropy_std']:.4f} | "
                     f"{r['weights_start']} -> {r['weights_trained']} |")
    if not rows:
        lines.append("| (no model with a gain prior) | | | | | |")
    return "\n".join(lines) + "\n"


def _ablation_verdict(a: dict[str, Any]) -> str:
    others = ", ".join(f"{k} {v:.4f}" for k, v in a["entropy"].items() if k != a["full"])
    full = a["entropy"].get(a["full"])
    head = (f"Under {a['noise']} noise, entropy at 100 %: {a['full']} "
            f"{'n/a' if full is None else f'{full:.4f}'} vs {others}.")
    if a["met"] is None:
        return head + " Not every arm was evaluated, so the ablation criterion cannot be checked."
    return head + (" The full model is at least as good as every ablation on entropy." if a["met"]
                   else " The full model is NOT at least as good as every ablation on entropy.")


def _latency_markdown(latency: list[dict[str, Any]]) -> str:
    lines = ["| Env | fusion | actor, one UAV (ms) | actor, batched (ms per UAV) | fusion (ms per UAV) | "
             "actor + fusion (ms) | AG (ms per UAV) |", "| --- | --- | ---: | ---: | ---: | ---: | ---: |"]
    for t in latency:
        fz = t["fusion_ms"]
        total = t["actor_ms_batch1"] + (fz or 0.0)
        lines.append(f"| {t['env']} | {t['fusion']} | {t['actor_ms_batch1']:.3f} | {t['actor_ms_batched']:.3f} | "
                     f"{'n/a' if fz is None else f'{fz:.4f}'} | {total:.3f} | {t['ag_ms']:.3f} |")
    return "\n".join(lines) + "\n"


def _ablation_section(summary: dict[str, Any]) -> list[str]:
    """RESULTS.md lines of the env3 ablation (none when it was not run)."""
    a = summary.get("ablation")
    if not a:
        return []
    return ["## Ablation: SenDFuse x CBAM under three noise levels (env3)", "",
            "The paper's Table II / Fig. 4. SenDFuse+CBAM is the env3 model above; the other three arms are the "
            "shipped models `env3-sendfuse-cnn`, `env3-mean-cbam`, `env3-mean-cnn`, trained with the same settings "
            "and selection (sb3_coma/pretrained/MODELS.md); each flown with the fusion it was trained with, same "
            "missions, argmax actions, at every noise level. Best of each noise level in bold. More in "
            "docs/ABLATION.md.", "", summary.get("ablation_table", ""), "", f"**{_ablation_verdict(a)}**", ""]


def _paired_section(summary: dict[str, Any]) -> list[str]:
    """RESULTS.md lines of the paired check (none when it was skipped)."""
    if not summary.get("paired_table"):
        return []
    return ["## A paired check on more missions", "",
            "The tables above rank methods by means over the trials, and the spread between missions is as large "
            "as several of the differences. Here each pair of methods flies the same missions, more of them, and "
            "the per-mission difference is averaged: ± is its standard error, and a difference within two "
            "standard errors is called a tie (`sb3_coma.paired`; `--wide-trials`). This checks the verdicts above; "
            "it does not replace them.", "", summary["paired_table"], ""]


def results_markdown(summary: dict[str, Any], table: str, figures: Sequence[Path], base: Path) -> str:
    """The RESULTS.md report from a summary (figure paths relative to ``base``)."""
    import os

    models = summary["models"]
    acc = summary["acceptance"]
    verdict = all(a["beats_all"] for a in acc.values()) if acc else False
    lines = [
        "# Results",
        "",
        f"Generated by `{summary['command']}` on {summary['date']} (Python {summary['python']}, "
        f"{summary['machine']}, CPU). {summary['trials']} seeded trials per method (env seeds "
        f"{summary['seed']}..{summary['seed'] + summary['trials'] - 1}, identical for every method), "
        f"4 UAVs, budget 15, channel noise `{summary['noise']}`. Every number on this page is measured by that command; "
        "regenerate it with `sb3-coma reproduce` (shipped models) or `sb3-coma reproduce --train` (retrain first).",
        "",
        "## Models",
        "",
        "| Env | source | fusion | actions | joint steps | training wall-clock (s) | retrain command |",
        "| --- | --- | --- | --- | ---: | ---: | --- |",
    ]
    for env, m in models.items():
        wall = "n/a" if m["train_wall_s"] is None else f"{float(m['train_wall_s']):.1f}"
        acts = "argmax" if m.get("deterministic", True) else "sampled (seeded)"
        lines.append(f"| {env} | {m['source'] if m['source'] == 'shipped' else 'trained by this run'} | {m['fusion']} | {acts} | "
                     f"{m['timesteps']} | {wall} | `{m['command']}` |")
    lines += ["", "Hyperparameters: `zoo_configs/coma.yml`; how they were chosen: `sb3_coma/pretrained/MODELS.md`.", "",
              "## Table I (mean ± std over trials; best of each env in bold)", "", table, "",
              "## Acceptance: COMA vs every baseline at 100 % of the budget", "",
              _acceptance_markdown(acc), "",
              ("**Verdict: COMA beats AG, NL (lawnmower) and random on both F1 and entropy on every evaluated "
               "environment.**") if verdict else
              "**Verdict: COMA does NOT beat every baseline on both metrics everywhere; see the NO cells above. "
              "What was tried and measured: `sb3_coma/pretrained/MODELS.md`.**", "",
              "## What training adds: the untrained gain prior vs the trained model (100 % budget)", "",
              "The shipped actor adds a learned mix of each action's expected information gain to its logits "
              "(docs/training.md, \"Gain prior\"). \"untrained prior\" flies the same model with that mix at its "
              "starting weights and the network's own term removed, argmax actions: the greedy planner the "
              "training starts from.", "", _prior_markdown(summary.get("untrained_prior", [])), "",
              *_ablation_section(summary),
              *_paired_section(summary),
              "## Generalisation (100 % budget)", "",
              "Each env's model flown on the other maps and on a fresh env1 star layout "
              f"(`map_seed={FRESH_ENV1_SEED}`; env1's default is 0), same trials and noise; baselines on the fresh layout "
              "for reference.", "", _generalisation_markdown(summary["generalisation"], summary["envs"], []), "",
              "## Deployment latency (per UAV decision, CPU)", "",
              "Actor = `model.predict` on one UAV's observation (batch of one, as on board) and batched over all trials "
              "as in evaluation; fusion = fusing the N received maps of one UAV; AG = its `predict` per UAV decision "
              "as timed by `evaluate` (batched over trials).", "", _latency_markdown(summary["latency"]), ""]
    if figures:
        lines += ["## Figures", ""]
        for f in figures:
            rel = os.path.relpath(f, base)
            lines += [f"![{Path(f).stem}]({rel})", ""]
    return "\n".join(lines) + "\n"
