"""``drill-env train``: train a PPO or SAC policy on the drill-string environment."""

from __future__ import annotations

import contextlib
import math
from contextlib import ExitStack
from pathlib import Path

import typer

from drill_env.agents._locations import PACKAGE_DIR, ROOT
from drill_env.outputs import fresh_run_folder

# what `drill-env train` writes into OUT and into its logs folder (a folder of these from
# before folders had markers is its own)
TRAIN_FILES = (
    "policy.zip",
    "config.yaml",
    "training_summary.json",
    "eval.csv",
    "progress.csv",
    "learning_curve.png",
    "policy.md",
)
TRAIN_LOG_FILES = ("final_policy.zip", "progress.csv", "events.out.tfevents.*")


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def _config_dirs() -> list[Path]:
    """The training configs: the source tree's configs/agents/ in a checkout, the copy
    installed with the package otherwise."""
    return [ROOT / "configs" / "agents", PACKAGE_DIR / "_configs" / "agents"]


def config_names() -> list[str]:
    """The names ``--config`` accepts in place of a path (``ppo``, ``v0/sac``, ...)."""
    names: set[str] = set()
    for d in _config_dirs():
        if d.is_dir():
            names.update(p.relative_to(d).with_suffix("").as_posix() for p in d.glob("**/*.yaml"))
    # the recipes of the committed policies first, then those in subfolders (experiments/, v0/)
    return sorted(
        (n for n in names if not n.startswith("rl_zoo3/") and n != "controllers"), key=lambda n: ("/" in n, n)
    )


def resolve_config(config: Path) -> Path:
    """``config`` itself if it is a file, else the config of that name (see
    :func:`config_names`); a ValueError naming both when neither exists."""
    if config.is_file() or config.suffix.lower() in (".yaml", ".yml"):
        return config  # a path: load_config reports a missing or bad file
    name = config.as_posix()
    if name in config_names():
        for d in _config_dirs():
            if (d / f"{name}.yaml").is_file():
                return d / f"{name}.yaml"
    raise ValueError(
        f"config: no file {str(config)!r} and no config of that name (names: {', '.join(config_names())})"
    )


def register(app: typer.Typer) -> None:
    @app.command("train")
    def train(
        algo: str = typer.Option(
            ..., help="Algorithm: ppo or sac (stable-baselines3), tqc or crossq (sb3-contrib)."
        ),
        config: Path = typer.Option(
            ...,
            help="Training config: a YAML file, or the name of one shipped with the package "
            "(from configs/agents/, works from any folder): the recipe of a committed policy by its "
            "name (ppo, sac, ppo_lqi_clone, ppo_robust, sac_no_brake, ...), a recipe tried and not kept "
            "(experiments/ppo_from_scratch, ...) or an earlier one (v0/ppo, ...).",
        ),
        seed: int = typer.Option(0, min=0, help="Random seed of the training run (>= 0)."),
        out: Path | None = typer.Option(
            None,
            help="Where the policy, config, summary and learning curve go. Default: a fresh "
            "run folder runs/train/NAME_seedN_TIME/NAME (NAME: ALGO or ALGO_no_brake; "
            "runs/train/.../vK/NAME for a -vK id older than the current one), laid out like "
            "results/agents so that `drill-env benchmark --agents-dir runs/train/NAME_seedN_TIME` "
            "evaluates it. The committed policies are regenerated only with an explicit "
            "--out results/agents/NAME (see results/README.md).",
        ),
        run_dir: Path | None = typer.Option(
            None,
            help="Where the CSV and TensorBoard logs and the final policy go (default: "
            "the run folder's logs/, or OUT/../logs/NAME with an explicit --out ending in NAME, so "
            "that runs into sibling folders keep their logs apart and one TensorBoard shows them all).",
        ),
        total_timesteps: int | None = typer.Option(None, help="Override the config's total_timesteps."),
        max_wall_time: float | None = typer.Option(
            None,
            "--max-wall-time",
            help="Stop training after this many wall-clock seconds (> 0; warm start and "
            "evaluations included), with one last evaluation; the evaluation-best policy is kept "
            "as always. Default: train for total_timesteps.",
        ),
        params: Path | None = typer.Option(
            None,
            "--params",
            help="Train on this rig model instead of the config's: a rig YAML in the preset format "
            "(effects included), e.g. a discrepancy result's model.yaml; sets env_kwargs.params.",
        ),
        progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
        trust_policies: bool = typer.Option(
            False,
            "--trust-policies",
            help="Load the warm start's teacher policy from outside results/agents/ (a "
            "$DRILL_ENV_AGENTS_DIR folder; loading one can run code it holds) in a run without a "
            "terminal, which otherwise refuses it; also DRILL_ENV_TRUST_POLICIES=1. On a "
            "terminal you are asked.",
        ),
    ) -> None:
        """Train ALGO on the config's environment; learning curve every evaluation.

        Writes OUT/policy.zip (the evaluation-best policy), OUT/config.yaml,
        OUT/training_summary.json (seed, steps, wall time, final/best evaluation return,
        converged by the plateau criterion), OUT/eval.csv, OUT/progress.csv,
        OUT/learning_curve.png and OUT/policy.md (the policy's card: how it started, its
        config, what it reached); the run's progress.csv and TensorBoard events go to RUN_DIR.
        """
        from drill_env.agents.learning.rl import ALGOS

        if algo not in ALGOS:
            _fail(f"--algo must be one of {list(ALGOS)}, got {algo!r}")
        if seed < 0:
            _fail(f"--seed must be >= 0, got {seed!r}")
        if total_timesteps is not None and total_timesteps < 1:
            _fail(f"--total-timesteps must be >= 1, got {total_timesteps!r}")
        if max_wall_time is not None and not (math.isfinite(max_wall_time) and max_wall_time > 0):
            _fail(f"--max-wall-time must be a positive number of seconds, got {max_wall_time!r}")
        from drill_env.outputs import check_command_folder

        if out is not None:  # before anything is loaded or written
            check_command_folder(out, "train", "--out", own=TRAIN_FILES)
        if run_dir is not None:
            check_command_folder(run_dir, "train", "--run-dir", own=TRAIN_LOG_FILES)
        from drill_env.agents.learning.rl import load_config
        from drill_env.agents.learning.rl import train as run_training

        try:
            config = resolve_config(config)
            cfg = load_config(config, total_timesteps=total_timesteps)
        except ValueError as exc:
            _fail(str(exc))
        if cfg.algo != algo:
            _fail(f"--algo {algo} does not match the config's algo {cfg.algo!r} ({config})")
        if params is not None:
            import dataclasses

            from drill_env.params import load_params

            if params.suffix not in (".yaml", ".yml") or not params.is_file():
                _fail(f"--params: {params} is not a rig YAML file (the preset format)")
            try:
                load_params(params)
            except ValueError as exc:
                _fail(f"--params: {exc}")
            cfg = dataclasses.replace(cfg, env_kwargs={**cfg.env_kwargs, "params": str(params.resolve())})
        teacher = None
        if cfg.warm_start is not None and cfg.warm_start.policy is not None:
            from drill_env.agents.commands._trust import vouch_for_policies
            from drill_env.agents.registry import policy_path, teacher_policy
            from drill_env.envs import ENV_IDS

            try:
                path = policy_path(cfg.warm_start.policy, ENV_IDS[cfg.env_id])
            except ValueError as exc:
                _fail(str(exc))
            trusted = vouch_for_policies([path], flag=trust_policies, option="warm_start.policy")
            try:  # a missing or mismatched teacher is bad input, found before any training
                teacher = teacher_policy(cfg.warm_start.policy, cfg.env_id, cfg.env_kwargs, trusted=trusted)
            except ValueError as exc:
                _fail(str(exc))
        from drill_env.envs import ENV_IDS, ENV_VERSIONS

        # laid out like results/agents: the policies of v1 and later at the top, v0's in v0/
        name = algo if ENV_IDS[cfg.env_id] == "brake" else f"{algo}_{ENV_IDS[cfg.env_id]}"
        version = ENV_VERSIONS[cfg.env_id]
        sub = Path(name) if version >= 1 else Path(f"v{version}") / name
        agents_dir = None
        if out is None:
            agents_dir = fresh_run_folder(Path("runs") / "train", f"{name}_seed{seed}")
            out = agents_dir / sub
        run_dir = run_dir or (
            agents_dir / "logs" if agents_dir is not None else out.parent / "logs" / out.name
        )
        typer.echo(
            f"training {algo} on {cfg.env_id} for {cfg.total_timesteps} steps, seed {seed}; "
            f"logs in {run_dir} (tensorboard --logdir {run_dir})"
        )

        def on_eval(step: int, ret: float) -> None:
            typer.echo(f"  eval at {step:>9d} steps: mean return {ret:9.2f}", err=True)

        from drill_env.outputs import OutputFolderError, command_folder

        held = ExitStack()
        try:
            # OUT and its logs are this training's alone until it ends
            held.enter_context(command_folder(out, "train", "--out", own=TRAIN_FILES))
            held.enter_context(command_folder(run_dir, "train", "--run-dir", own=TRAIN_LOG_FILES))
        except OutputFolderError as exc:
            held.close()
            if agents_dir is not None:
                with contextlib.suppress(OSError):
                    agents_dir.rmdir()
            _fail(str(exc))
        with held:
            summary = run_training(
                cfg,
                seed,
                out,
                run_dir,
                progress_bar=progress,
                on_eval=on_eval,
                teacher=teacher,
                max_wall_time_s=max_wall_time,
            )
            from drill_env.agents.learning.cards import write_policy_card

            write_policy_card(out, config)  # how it started, its config, what it reached
        verdict = "converged" if summary["converged"] else "NOT converged"
        typer.echo(
            f"{algo}: {summary['total_timesteps']} steps in {summary['wall_time_s']:.0f} s"
            f"{' (stopped at the wall-time budget)' if summary['stopped_by'] == 'max_wall_time' else ''}; "
            f"final eval return {summary['final_eval_return']:.2f}, best {summary['best_eval_return']:.2f} "
            f"at {summary['best_at_timesteps']} steps; {verdict} ({summary['convergence']['reason']})"
        )
        refs = ", ".join(f"{k} {v:.2f}" for k, v in summary["reference_returns"].items())
        typer.echo(f"references on the same episodes: {refs}")
        typer.echo(f"wrote {out}/policy.zip, training_summary.json, learning_curve.png, policy.md")
        if agents_dir is not None:
            typer.echo(
                f"benchmark it: drill-env benchmark --quick --agents-dir {agents_dir} --out {agents_dir}/benchmark"
            )
