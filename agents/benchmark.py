"""The controller benchmark: every controller over a grid of operating points and seeds.

Each run is one call of :func:`agents.evaluation.evaluate` (the one evaluation path) with a
key (controller, preset, voltage, seed); all controllers see the same initial states and
sensor noise at the same key. Runs execute

* ``backend="process"`` (default): in a local pool of worker processes;
* ``backend="sequential"``: in this process;
* ``backend="ray"``: as Ray tasks, on a local Ray instance or a cluster (``address``; the
  package must be importable on every node), with ``pip install drill-env[ray]``;

each finished run is appended to ``DIR/benchmark.csv`` at once, so an interrupted
benchmark resumes where it stopped: runs whose key is already in the CSV (without an
error) are skipped. ``DIR/benchmark_config.json`` records the episode settings; resuming
with different ones is refused. One benchmark at a time writes into ``DIR``: it holds
``DIR/.drill-env.lock`` for the whole run (see :mod:`drill_env.outputs`), and a second one
started on the same folder stops at once with an error naming the first.

At the end the CSV is rewritten in grid order and the report is made from it:
``summary.md`` (a table per preset and regime, and the suppression at every voltage),
``bifurcation_<preset>.png`` (the bifurcation diagram of the analysis with each
controller's steady min/max of x3) and ``suppression_<preset>.png``.
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
import os
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation import IDENTIFIED_SPEED, METRIC_COLUMNS, EpisodeSettings
from agents.plants import NOMINAL, Plant
from agents.registry import CONTROLLERS
from agents.robustness import COLORS, REGIMES, ordered_controllers, robustness_figure, robustness_lines
from drill_env.outputs import atomic_file, atomic_write_text, output_lock
from drill_env.params import PRESETS

__all__ = [
    "BACKENDS",
    "FULL_GRID",
    "QUICK_GRID",
    "BenchmarkConfig",
    "Job",
    "run_benchmark",
    "write_report",
    "load_results",
]

BACKENDS = ("process", "sequential", "ray")
# the plant a run's rig is (after the preset whose controllers and operating points it uses)
COLUMNS = METRIC_COLUMNS[:2] + ("plant",) + METRIC_COLUMNS[2:] + ("error",)
KEY = ("controller", "preset", "plant", "voltage", "seed")
# up to this many plants besides the nominal one get a suppression figure each; more are
# drawn as small multiples in one figure
SEPARATE_PLANT_FIGURES = 3
# the figures write_report makes (removed with the results by ``fresh``)
REPORT_FIGURES = ("bifurcation_*.png", "suppression_*.png", "robustness_*.png", "timeseries_*.png")
# [rad/s] below this open-loop amplitude a plant has no cycle to suppress (suppression NaN):
# the closed loops leave a steady amplitude of 0.005-0.05 rad/s from encoder quantisation on
# the nominal model, so a smaller "cycle" cannot be suppressed measurably (the smallest cycle
# the analysis predicts on the grid is 1.2 rad/s)
OPEN_LOOP_FLOOR = 0.1

# Voltages [V] of the grid per preset. Brake: 0.2-5 V across the three regimes (A = 0.116,
# Hopf B = 0.583, stick-slip from D = 1.781 V). No brake: every regime of Fig. 8(a)
# (B = 0.489, D = 0.600, E = 1.294, C = 1.430, F = 1.661 V).
FULL_GRID: dict[str, tuple[float, ...]] = {
    "brake": (0.2, 0.3, 0.4, 0.5, 0.7, 0.85, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0),
    "no_brake": (0.2, 0.3, 0.4, 0.55, 0.7, 0.85, 1.0, 1.15, 1.35, 1.5, 1.6, 1.8, 2.5, 3.5, 5.0),
}
QUICK_GRID: dict[str, tuple[float, ...]] = {
    "brake": (0.4, 1.0, 2.0, 4.0),
    "no_brake": (0.3, 0.55, 1.0, 1.5),
}
FULL_SEEDS = (0, 1, 2, 3, 4)
QUICK_SEEDS = (0,)
REGIME_TITLES = REGIMES  # regime -> the title of its table


@dataclass(frozen=True)
class Job:
    controller: str
    preset: str
    voltage: float
    seed: int
    plant: str = NOMINAL

    @property
    def key(self) -> tuple[str, str, str, float, int]:
        return (self.controller, self.preset, self.plant, round(self.voltage, 9), self.seed)


@dataclass(frozen=True)
class BenchmarkConfig:
    """The grid and the episode settings of a benchmark."""

    presets: tuple[str, ...] = PRESETS
    controllers: tuple[str, ...] = CONTROLLERS
    voltages: Mapping[str, tuple[float, ...]] = field(default_factory=lambda: dict(FULL_GRID))
    seeds: tuple[int, ...] = FULL_SEEDS
    episode: EpisodeSettings = field(default_factory=EpisodeSettings)
    agents_dir: str | None = None  # where the trained policies are (default: results/agents)
    gains_file: str | None = None  # tuned gains (default: configs/agents/controllers.yaml)
    plants: tuple[Plant, ...] = (Plant(),)  # the rigs every controller runs on

    def __post_init__(self) -> None:
        from drill_env.envs.task import VOLTAGE_LIMIT
        from drill_env.params import load_params

        if not self.presets:
            raise ValueError(f"presets: expected at least one of {list(PRESETS)}")
        for p in self.presets:
            if p not in PRESETS:
                raise ValueError(f"presets: {p!r} is not one of {list(PRESETS)}")
        if not self.controllers:
            raise ValueError(f"controllers: expected at least one of {list(CONTROLLERS)}")
        for c in self.controllers:
            if c not in CONTROLLERS:
                raise ValueError(f"controllers: {c!r} is not one of {list(CONTROLLERS)}")
        if not self.seeds:
            raise ValueError("seeds: expected at least one seed")
        for s in self.seeds:
            if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
                raise ValueError(f"seeds: {s!r} is not an integer >= 0")
        volts = {}
        for p in self.presets:
            vs = tuple(float(v) for v in self.voltages.get(p, ()))
            if not vs:
                raise ValueError(f"voltages: no voltages for preset {p!r}")
            uc1 = load_params(p).uc1
            for v in vs:
                if not (math.isfinite(v) and uc1 < v <= VOLTAGE_LIMIT):
                    raise ValueError(
                        f"voltages: {v!r} V for {p!r} is outside the allowed range ({uc1:.4g}, {VOLTAGE_LIMIT:g}] V"
                    )
            volts[p] = vs
        if not self.plants or not all(isinstance(p, Plant) for p in self.plants):
            raise ValueError("plants: expected one or more Plant (default: the nominal model)")
        names = [p.name for p in self.plants]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"plants: the name(s) {dup} appear twice (a plant is named by its file's stem)")
        object.__setattr__(self, "plants", tuple(self.plants))
        object.__setattr__(self, "voltages", volts)
        object.__setattr__(self, "presets", tuple(self.presets))
        object.__setattr__(self, "controllers", tuple(self.controllers))
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))

    @classmethod
    def preset_grid(
        cls, presets: Sequence[str] = PRESETS, *, quick: bool = False, **kwargs: Any
    ) -> BenchmarkConfig:
        grid = QUICK_GRID if quick else FULL_GRID
        kwargs.setdefault("seeds", QUICK_SEEDS if quick else FULL_SEEDS)
        return cls(presets=tuple(presets), voltages={p: grid[p] for p in presets}, **kwargs)

    def plant(self, name: str) -> Plant:
        for p in self.plants:
            if p.name == name:
                return p
        raise ValueError(f"plant: {name!r} is not one of {[p.name for p in self.plants]}")

    def jobs(self) -> list[Job]:
        return [
            Job(c, p, v, s, plant.name)
            for p in self.presets
            for plant in self.plants
            for v in self.voltages[p]
            for s in self.seeds
            for c in self.controllers
        ]

    def settings_record(self) -> dict[str, Any]:
        """What must match for a resumed benchmark (the grid may grow)."""
        rec: dict[str, Any] = {"episode": self.episode.to_dict()}
        if any(not p.is_nominal for p in self.plants):
            rec["plants"] = [p.record() for p in self.plants if not p.is_nominal]
        return rec


# -- one run, in whichever process ---------------------------------------------------------------

_ENVS: dict[tuple[str, str], Any] = {}
_CONTROLLERS: dict[tuple[Any, ...], Any] = {}


def _worker_init() -> None:
    import torch

    torch.set_num_threads(1)


def run_job(job: Job, cfg: BenchmarkConfig) -> dict[str, Any]:
    """Evaluate one job; environments and controllers are cached per process. An exception
    becomes a row with NaN metrics and the message in ``error``."""
    from agents.evaluation import evaluate, make_env
    from agents.registry import build_controller, observation_version

    t0 = time.perf_counter()
    try:
        # cached per process, keyed by everything they are built from
        version = observation_version(job.controller, job.preset, cfg.agents_dir)
        episode_key = json.dumps(cfg.episode.to_dict(), sort_keys=True, default=str)

        def env_of(plant: str, v: int):
            key = (job.preset, v, episode_key, plant)
            if key not in _ENVS:
                q = cfg.plant(plant)
                _ENVS[key] = make_env(
                    job.preset, cfg.episode, v, params=q.rig(job.preset), overrides=q.env_overrides()
                )
            return _ENVS[key]

        # the controller is built on the nominal model (its design), then run on the plant
        design_env = env_of(NOMINAL, version)
        ctrl_key = (job.controller, job.preset, version, episode_key, cfg.agents_dir, cfg.gains_file)
        ctrl = _CONTROLLERS.get(ctrl_key)
        if ctrl is None:
            ctrl = _CONTROLLERS[ctrl_key] = build_controller(
                job.controller, design_env, job.preset, agents_dir=cfg.agents_dir, gains_file=cfg.gains_file
            )
        reference = None if job.plant == NOMINAL else _plant_open_loop(job, cfg, env_of(job.plant, 0))
        row = evaluate(
            ctrl,
            job.preset,
            job.voltage,
            job.seed,
            cfg.episode,
            name=job.controller,
            env=env_of(job.plant, version),
            open_loop_amplitude=reference,
        ).as_dict()
        row["plant"] = job.plant
        row["error"] = ""
    except Exception as exc:  # recorded, the benchmark goes on
        row = {c: math.nan for c in COLUMNS}
        row.update(
            controller=job.controller, preset=job.preset, plant=job.plant, voltage=job.voltage, seed=job.seed
        )
        row.update(regime="", sim_status=-1, wall_time=time.perf_counter() - t0)
        row["error"] = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:300]
    return row


_OPEN_LOOP: dict[tuple[Any, ...], float] = {}


def _plant_open_loop(job: Job, cfg: BenchmarkConfig, env: Any) -> float:
    """The open-loop amplitude on ``job``'s plant at its voltage and seed (cached per process):
    the reference of the suppression where the bifurcation analysis (nominal model) does not
    apply. 0 below :data:`OPEN_LOOP_FLOOR` (no cycle: suppression NaN)."""
    from agents.base import ControllerSpec
    from agents.evaluation import evaluate
    from agents.open_loop import OpenLoop

    key = (
        job.preset,
        job.plant,
        round(job.voltage, 9),
        job.seed,
        json.dumps(cfg.episode.to_dict(), default=str),
    )
    if key not in _OPEN_LOOP:
        m = evaluate(
            OpenLoop(ControllerSpec.from_env(env)),
            job.preset,
            job.voltage,
            job.seed,
            cfg.episode,
            env=env,
            open_loop_amplitude=0.0,
        )
        _OPEN_LOOP[key] = m.amplitude if m.amplitude >= OPEN_LOOP_FLOOR else 0.0
    return _OPEN_LOOP[key]


def _run_chunk(jobs: list[Job], cfg: BenchmarkConfig) -> list[dict[str, Any]]:
    _worker_init()
    return [run_job(j, cfg) for j in jobs]


# -- results file ----------------------------------------------------------------------------------


def _key_of_row(row: Mapping[str, Any]) -> tuple[str, str, str, float, int]:
    return (
        str(row["controller"]),
        str(row["preset"]),
        str(row.get("plant") or NOMINAL),
        round(float(row["voltage"]), 9),
        int(float(row["seed"])),
    )


def load_results(path: str | Path):
    """The benchmark CSV as a pandas DataFrame."""
    import pandas as pd

    text = ("controller", "preset", "plant", "regime", "error")
    df = pd.read_csv(path, dtype={c: object for c in text})
    if "plant" not in df.columns:  # a CSV from before plants: every run on the nominal model
        df.insert(2, "plant", NOMINAL)
    if "x3_peak_abs" not in df.columns and {"x3_min", "x3_max", "preset"} <= set(df.columns):
        # a CSV written before these columns existed: the peak of its scoring window
        df["x3_peak_abs"] = np.maximum(df["x3_min"].abs(), df["x3_max"].abs())
        limit = df["preset"].map(lambda p: IDENTIFIED_SPEED.get(str(p), math.inf)).astype(float)
        df["beyond_identified_range"] = df["x3_peak_abs"] > limit
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; expected {list(COLUMNS)}")
    for c in text:
        df[c] = df[c].where(df[c].notna(), "").astype(str)
    flags = ("beyond_identified_range",)
    for c in COLUMNS:
        if c not in text and c not in flags:
            df[c] = df[c].astype(float)
    for c in flags:
        df[c] = df[c].map(lambda v: str(v).strip().lower() in ("true", "1", "1.0"))
    df["seed"] = df["seed"].astype(int)
    df["sim_status"] = df["sim_status"].astype(int)
    return df


def check_resumable(cfg: BenchmarkConfig, out_dir: str | Path) -> dict[str, Any] | None:
    """Check, writing nothing, that the benchmark in ``out_dir`` (if any) can be resumed with
    ``cfg``: its settings record and results file are readable and the episode settings and
    plants agree. Returns the settings record (None: nothing to resume); raises ValueError
    naming the file otherwise."""
    out = Path(out_dir)
    csv_path = out / "benchmark.csv"
    cfg_path = out / "benchmark_config.json"
    if not (cfg_path.is_file() and csv_path.is_file()):
        return None
    record = cfg.settings_record()
    old = _read_settings(cfg_path)
    if old.get("episode") != json.loads(json.dumps(record["episode"])):
        raise ValueError(
            f"out: {out} holds a benchmark with other episode settings ({old.get('episode')}); "
            "use another directory or --fresh to start over"
        )
    before = {q["name"]: q for q in old.get("plants", [])}
    for q in json.loads(json.dumps(record.get("plants", []))):
        if q["name"] in before and before[q["name"]] != q:
            raise ValueError(
                f"plant: {q['name']!r} in {out} was run with other parameters; rename the plant "
                "file, use another directory or --fresh to start over"
            )
    _done_keys(csv_path)
    return old


def _drop_partial_row(csv_path: Path) -> None:
    """Cut a last row that an interrupted run left without its line end (it is run again)."""
    if not csv_path.is_file():
        return
    data = csv_path.read_bytes()
    if not data or data.endswith(b"\n"):
        return
    keep = data.rfind(b"\n") + 1
    warnings.warn(
        f"{csv_path}: the last row is incomplete (an interrupted run); it is dropped and run again",
        RuntimeWarning,
        stacklevel=3,
    )
    with open(csv_path, "r+b") as f:
        f.truncate(keep)


def _done_keys(csv_path: Path) -> set[tuple[str, str, float, int]]:
    if not csv_path.is_file():
        return set()
    data = csv_path.read_bytes()
    source: Path | io.BytesIO = csv_path
    if data and not data.endswith(b"\n"):  # an interrupted run's last row: run it again
        source = io.BytesIO(data[: data.rfind(b"\n") + 1])
    try:
        df = load_results(source)
        ok = df[df["error"] == ""]
        return {_key_of_row(r) for r in ok.to_dict("records")}
    except (ValueError, KeyError, IndexError) as exc:  # pandas' parser and cast errors are ValueErrors
        detail = " ".join(str(exc).split())
        raise ValueError(
            f"{csv_path}: cannot resume from it ({detail}); repair or remove the file, or start over with "
            "--fresh"
        ) from None


def _read_settings(cfg_path: Path) -> dict[str, Any]:
    """The settings record of the benchmark in a folder, or an error naming the file."""
    try:
        old = json.loads(cfg_path.read_text(encoding="utf-8"))
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        detail = " ".join(str(exc).split())
        raise ValueError(
            f"{cfg_path}: not a valid settings record ({detail}); it is needed to resume the benchmark "
            f"in {cfg_path.parent}: repair it, or start over with --fresh"
        ) from None
    plants = old.get("plants", []) if isinstance(old, dict) else None
    if not isinstance(plants, list) or not all(isinstance(q, dict) and "name" in q for q in plants):
        raise ValueError(
            f"{cfg_path}: not a valid settings record (expected a JSON object with 'episode'); "
            "repair it, or start over with --fresh"
        )
    return old


class _Writer:
    def __init__(self, path: Path):
        new = not path.is_file() or path.stat().st_size == 0
        if not new:
            with open(path, newline="") as f:
                header = next(csv.reader(f), [])
            if header != list(COLUMNS):  # an older layout: rewrite it in this one, then append
                df = load_results(path)
                with atomic_file(path, "w", newline="") as f:
                    w = csv.DictWriter(f, fieldnames=list(COLUMNS))
                    w.writeheader()
                    for row in df.to_dict("records"):
                        w.writerow({c: _fmt(row[c]) for c in COLUMNS})
        self.f = open(path, "a", newline="")
        self.w = csv.DictWriter(self.f, fieldnames=list(COLUMNS))
        if new:
            self.w.writeheader()
            self.f.flush()

    def write(self, row: Mapping[str, Any]) -> None:
        self.w.writerow({c: _fmt(row.get(c)) for c in COLUMNS})
        self.f.flush()
        os.fsync(self.f.fileno())

    def close(self) -> None:
        self.f.close()


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.10g}"
    return v


# -- the benchmark ---------------------------------------------------------------------------------


def _chunks(jobs: list[Job], size: int) -> list[list[Job]]:
    return [jobs[i : i + size] for i in range(0, len(jobs), size)]


def run_benchmark(
    cfg: BenchmarkConfig,
    out_dir: str | Path,
    *,
    backend: str = "process",
    workers: int | None = None,
    ray_address: str | None = None,
    fresh: bool = False,
    progress: Callable[[int, int, dict[str, Any]], None] | None = None,
    report: bool = True,
) -> Path:
    """Run (or resume) the benchmark into ``out_dir``; returns the CSV path.

    ``progress(done, total, row)`` is called after every finished run. The folder is held
    for the whole run (:func:`drill_env.outputs.output_lock`): another benchmark on it raises
    :class:`drill_env.outputs.OutputFolderBusy` (a ValueError) before touching anything.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend: {backend!r} is not one of {list(BACKENDS)}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers: expected an integer >= 1, got {workers!r}")
    out = Path(out_dir)
    with output_lock(out, "benchmark"):
        return _run_benchmark(cfg, out, backend, workers, ray_address, fresh, progress, report)


def _run_benchmark(
    cfg: BenchmarkConfig,
    out: Path,
    backend: str,
    workers: int | None,
    ray_address: str | None,
    fresh: bool,
    progress: Callable[[int, int, dict[str, Any]], None] | None,
    report: bool,
) -> Path:
    csv_path = out / "benchmark.csv"
    cfg_path = out / "benchmark_config.json"
    record = cfg.settings_record()
    if fresh:  # the results and the report made from them (no stale figure of a plant left)
        report = [out / "summary.md"] + [
            f for pattern in REPORT_FIGURES for f in (out.glob(pattern) if out.is_dir() else [])
        ]
        for p in (csv_path, cfg_path, *report):
            if p.is_file():
                p.unlink()
    old = check_resumable(cfg, out)
    _drop_partial_row(csv_path)
    if old is not None:
        before = {q["name"]: q for q in old.get("plants", [])}
        record = (
            dict(
                record,
                plants=list(
                    {**before, **{q.name: q.record() for q in cfg.plants if not q.is_nominal}}.values()
                ),
            )
            if before
            else record
        )
    full_record = dict(
        record,
        presets=list(cfg.presets),
        controllers=list(cfg.controllers),
        voltages={p: list(v) for p, v in cfg.voltages.items()},
        seeds=list(cfg.seeds),
        policies=_policies_used(cfg),
        plant_notes=[
            {
                "name": q.name,
                "source": q.source,
                "description": q.description,
                "effects": q.effects_on(cfg.presets[0]),
                "scale": dict(q.scale),
                "sensors": dict(q.sensors),
                "family": q.friction_family(),
            }
            for q in cfg.plants
        ],
    )
    atomic_write_text(cfg_path, json.dumps(full_record, indent=2) + "\n")
    done = _done_keys(csv_path)
    all_jobs = cfg.jobs()
    todo = [j for j in all_jobs if j.key not in done]
    total = len(all_jobs)
    n_done = total - len(todo)
    writer = _Writer(csv_path)
    try:
        if progress is not None:
            progress(n_done, total, {})

        def finish(row: dict[str, Any]) -> None:
            nonlocal n_done
            writer.write(row)
            n_done += 1
            if progress is not None:
                progress(n_done, total, row)

        if todo:
            if backend == "sequential":
                _worker_init()
                for j in todo:
                    finish(run_job(j, cfg))
            elif backend == "process":
                _run_process_pool(todo, cfg, workers or max(1, os.cpu_count() or 1), finish)
            else:
                _run_ray(todo, cfg, workers, ray_address, finish)
    finally:
        writer.close()
    missing = {j.key for j in all_jobs} - _rewrite_sorted(csv_path, cfg)
    if missing:  # only if something bypassed the lock
        raise RuntimeError(
            f"{csv_path}: {len(missing)} of {total} runs are missing after the benchmark "
            f"(e.g. {sorted(missing)[0]}); was the file changed by another process?"
        )
    if report:
        write_report(csv_path, out)
    return csv_path


def _policy_note(text: str) -> str:
    """``path on ENV-ID`` -> ```path``` on ``ENV-ID`` (markdown)."""
    path, _, env_id = text.partition(" on ")
    return f"`{path}` on `{env_id}`" if env_id else f"`{path}`"


def _policies_used(cfg: BenchmarkConfig) -> dict[str, str]:
    """Which trained policy each learned controller runs per preset (for the report)."""
    from agents.registry import LEARNED, default_agents_dir, policy_path

    root = Path(cfg.agents_dir) if cfg.agents_dir is not None else default_agents_dir()
    out = {}
    for c in cfg.controllers:
        if c not in LEARNED:
            continue
        for p in cfg.presets:
            try:
                path = policy_path(c, p, cfg.agents_dir)
                shown = (
                    str(path.relative_to(root.parent.parent))
                    if root.parent.parent in path.parents
                    else str(path)
                )
                try:
                    from agents.evaluation import env_id_of
                    from agents.rl import policy_observation_version

                    shown += f" on {env_id_of(p, policy_observation_version(path))}"
                except ValueError:
                    pass
                out[f"{c}/{p}"] = shown
            except ValueError as exc:
                out[f"{c}/{p}"] = f"missing ({exc})"
    return out


def _run_process_pool(todo: list[Job], cfg: BenchmarkConfig, workers: int, finish) -> None:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # Small chunks: the pool stays busy and an interruption loses little.
    size = max(1, min(8, len(todo) // (4 * workers) or 1))
    ctx = mp.get_context("spawn")  # torch and numba threads do not survive fork safely
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init)
    try:
        pending = {pool.submit(_run_chunk, chunk, cfg) for chunk in _chunks(todo, size)}
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                for row in fut.result():
                    finish(row)
    except BaseException:
        # interrupted: what is written stays written; do not wait for the queued runs
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _run_ray(todo: list[Job], cfg: BenchmarkConfig, workers: int | None, address: str | None, finish) -> None:
    try:
        import ray
    except ImportError:
        raise ValueError("backend: 'ray' needs Ray; install it with `pip install drill-env[ray]`") from None
    started = False
    if not ray.is_initialized():
        if address:
            ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
        else:
            ray.init(
                num_cpus=workers or os.cpu_count() or 1,
                ignore_reinit_error=True,
                log_to_driver=False,
                include_dashboard=False,
            )
        started = True
    try:
        remote = ray.remote(num_cpus=1)(_run_chunk)
        size = max(1, min(8, len(todo) // (4 * (workers or 2)) or 1))
        cfg_ref = ray.put(cfg)
        pending = [remote.remote(chunk, cfg_ref) for chunk in _chunks(todo, size)]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for row in ray.get(ready[0]):
                finish(row)
    finally:
        if started:
            ray.shutdown()


def _rewrite_sorted(csv_path: Path, cfg: BenchmarkConfig) -> set[tuple[str, str, float, int]]:
    """Rewrite the CSV in grid order, the last row of every key kept; returns the keys."""
    df = load_results(csv_path)
    df["_key"] = [_key_of_row(r) for r in df.to_dict("records")]
    df = df.drop_duplicates("_key", keep="last")
    df_keys = list(df["_key"])
    order_c = {c: i for i, c in enumerate(CONTROLLERS)}
    order_p = {p: i for i, p in enumerate(PRESETS)}
    order_q = {q.name: i for i, q in enumerate(cfg.plants)}
    df["_c"] = df["controller"].map(order_c)
    df["_p"] = df["preset"].map(order_p)
    df["_q"] = df["plant"].map(lambda q: order_q.get(q, len(order_q)))
    df = df.sort_values(["_p", "_q", "plant", "voltage", "seed", "_c"]).drop(
        columns=["_key", "_c", "_p", "_q"]
    )
    with atomic_file(csv_path, "w", newline="") as f:  # a temporary file of its own, then one replace
        w = csv.DictWriter(f, fieldnames=list(COLUMNS))
        w.writeheader()
        for row in df.to_dict("records"):
            w.writerow({c: _fmt(row[c]) for c in COLUMNS})
    return set(df_keys)


# -- report ----------------------------------------------------------------------------------------


def _num(x: float, digits: int = 3) -> str:
    """Fixed-point text without a minus sign on a rounded zero."""
    t = f"{x:.{digits}f}"
    return t[1:] if t.startswith("-") and float(t) == 0.0 else t


def _plant_heading(preset: str, plant: str, info: Mapping[str, Any] | None) -> list[str]:
    if plant == NOMINAL:
        return [
            f"## {preset}, plant `{NOMINAL}`",
            "",
            "The preset's own model, on which every controller was designed; open-loop reference: "
            "the bifurcation analysis.",
            "",
        ]
    info = info or {}
    effects = ", ".join(info.get("effects") or []) or "none"
    what = (
        f"The nominal `{preset}` model with {info['description']}"
        if info.get("description")
        else f"Rig `{info.get('source', plant)}`"
    )
    lines = [
        f"## {preset}, plant `{plant}`",
        "",
        f"{what} (effects: {effects}). The controllers keep their design on "
        f"the nominal `{preset}` model; open-loop reference: the open-loop run on this plant at the "
        "same voltage and seed (no cycle below "
        f"{OPEN_LOOP_FLOOR:g} rad/s: suppression `-`). Regimes are the nominal model's at each voltage.",
        "",
    ]
    family = info.get("family")
    if family and family != preset:
        lines += [
            f"**Note:** this plant's lower-disk friction is closer to the `{family}` preset than to "
            f"`{preset}`, whose controllers run on it here.",
            "",
        ]
    return lines


def summary_tables(
    df, notes: Mapping[str, str] | None = None, plants: Mapping[str, Mapping[str, Any]] | None = None
) -> str:
    """The markdown of ``summary.md`` from the results DataFrame."""
    lines = [
        "# Controller benchmark",
        "",
        "Every controller at every operating point (nominal voltage u) and seed, switched on at a",
        "random phase of the open-loop behaviour after an open-loop warm-up; metrics of the lower-disk",
        "speed x3 over the last window of the episode, from the true state (see `agents/evaluation.py`).",
        "Suppression = 1 - amplitude / open-loop amplitude predicted by the bifurcation analysis",
        "(1: cycle removed, 0: as open loop, < 0: worse); it is defined only where the analysis",
        "predicts a cycle. Means over the runs of a regime, worst case in brackets; peak |u| is the",
        "largest over the runs. |u| and the time at the 5 V limit are over the whole closed-loop",
        "episode.",
        "",
        "Terms: *amplitude* = max - min of x3 over the window [rad/s]; *open-loop amplitude* = the",
        "same on the limit cycle the analysis predicts at u (0: a stable equilibrium); *stuck* = time",
        "fraction with the lower disk stuck; *severity* = (max - min) / (2 mean) of x3, the usual",
        "stick-slip severity (1 or more: the bit stops in each cycle); *RMS error* = RMS of x3 - w*,",
        "w* the target speed. The brake's friction model was identified up to 12.6 rad/s only",
        "(Sec. 4 of the paper): *beyond 12.6 rad/s* counts the runs whose |x3| exceeded that at any",
        "time of the closed-loop episode (CSV: `beyond_identified_range`, `x3_peak_abs`); their",
        "figures are outside what the model vouches for.",
        "",
    ]
    ok = df[df["error"] == ""]
    failed = df[df["error"] != ""]
    only_nominal = set(df["plant"]) <= {NOMINAL}
    sections = [
        (preset, plant)
        for preset in PRESETS
        if preset in set(df["preset"])
        for plant in _plants_in(df[df["preset"] == preset])
    ]
    for preset, plant in sections:
        sub = ok[(ok["preset"] == preset) & (ok["plant"] == plant)]
        names = _plants_in(df[df["preset"] == preset])
        if plant == names[0] and len(names) > 1:
            lines += robustness_lines(df, preset, plants)
        if only_nominal:
            lines += [f"## {preset}", ""]
        else:
            lines += _plant_heading(preset, plant, (plants or {}).get(plant))
        used = {k.split("/")[0]: v for k, v in (notes or {}).items() if k.endswith(f"/{preset}")}
        if used:
            lines.append(
                "Learned policies: " + "; ".join(f"{c}: {_policy_note(v)}" for c, v in used.items()) + "."
            )
            lines.append("")
        for regime, title in REGIME_TITLES.items():
            reg = sub[sub["regime"] == regime]
            if reg.empty:
                continue
            volts = sorted(set(reg["voltage"]))
            vtxt = ", ".join(f"{v:g}" for v in volts)
            lines.append(f"### {title} ({vtxt} V; {reg['seed'].nunique()} seed(s))")
            lines.append("")
            lines.append(
                "| controller | suppression | amplitude [rad/s] | open-loop amplitude [rad/s] | stuck [%] | "
                "severity | RMS error [rad/s] | mean \\|u\\| [V] | peak \\|u\\| [V] | at 5 V limit [%] | runs |"
                + (
                    f" beyond {IDENTIFIED_SPEED[preset]:g} rad/s [runs] |"
                    if preset in IDENTIFIED_SPEED
                    else ""
                )
            )
            lines.append(
                "|---|---|---|---|---|---|---|---|---|---|---|"
                + ("---|" if preset in IDENTIFIED_SPEED else "")
            )
            for c in ordered_controllers(reg["controller"]):
                r = reg[reg["controller"] == c]
                sup = r["suppression"].dropna()
                sup_txt = f"{_num(sup.mean())} ({_num(sup.min())})" if len(sup) else "-"
                cells = [
                    c,
                    sup_txt,
                    f"{_num(r['amplitude'].mean())} ({_num(r['amplitude'].max())})",
                    _num(r["open_loop_amplitude"].mean()),
                    f"{_num(100 * r['stick_fraction'].mean(), 1)} ({_num(100 * r['stick_fraction'].max(), 1)})",
                    _num(r["severity"].mean()),
                    f"{_num(r['rms_error'].mean())} ({_num(r['rms_error'].max())})",
                    _num(r["u_mean_abs"].mean(), 2),
                    _num(r["u_peak_abs"].max(), 2),
                    _num(100 * r["u_limit_fraction"].mean(), 1),
                    str(len(r)),
                ]
                if preset in IDENTIFIED_SPEED:
                    n_out = int(r["beyond_identified_range"].sum())
                    cells.append(f"**{n_out}**" if n_out else "0")
                lines.append("| " + " | ".join(cells) + " |")
            lines.append("")
        # suppression at every voltage
        cyc = sub[sub["open_loop_amplitude"] > 0]
        if not cyc.empty:
            volts = sorted(set(cyc["voltage"]))
            lines.append("### suppression at each voltage (mean over seeds)")
            lines.append("")
            lines.append("| controller | " + " | ".join(f"{v:g} V" for v in volts) + " |")
            lines.append("|---|" + "---|" * len(volts))
            for c in ordered_controllers(cyc["controller"]):
                r = cyc[cyc["controller"] == c]
                cells = []
                for v in volts:
                    s = r[r["voltage"] == v]["suppression"]
                    cells.append(_num(s.mean(), 2) if len(s) else "-")
                lines.append(f"| {c} | " + " | ".join(cells) + " |")
            lines.append("")
    if not failed.empty:
        lines.append("## runs that failed")
        lines.append("")
        for r in failed.to_dict("records"):
            on = "" if r["plant"] == NOMINAL else f" (plant {r['plant']})"
            lines.append(
                f"- {r['controller']} {r['preset']}{on} {r['voltage']:g} V seed {int(r['seed'])}: {r['error']}"
            )
        lines.append("")
    return "\n".join(lines)


def write_report(csv_path: str | Path, out_dir: str | Path) -> list[Path]:
    """``summary.md`` and the figures from a benchmark CSV."""
    df = load_results(csv_path)
    out = Path(out_dir)
    notes = None
    plants: dict[str, dict[str, Any]] = {}
    cfg_path = Path(csv_path).parent / "benchmark_config.json"
    if cfg_path.is_file():
        rec = json.loads(cfg_path.read_text())
        notes = rec.get("policies")
        plants = {p["name"]: p for p in rec.get("plant_notes", [])}
    paths = [out / "summary.md"]
    atomic_write_text(paths[0], summary_tables(df, notes, plants) + "\n")
    for preset in [p for p in PRESETS if p in set(df["preset"])]:
        names = _plants_in(df[df["preset"] == preset])
        others = [q for q in names if q != NOMINAL]
        many = len(others) > SEPARATE_PLANT_FIGURES
        for plant in names if not many else [q for q in names if q == NOMINAL]:
            sel = (df["preset"] == preset) & (df["plant"] == plant) & (df["error"] == "")
            paths += _figures(df[sel], preset, out, plant)
        if many:
            paths.append(_plants_figure(df, preset, out, others))
        if len(names) > 1:
            paths.append(robustness_figure(df, preset, out))
    return paths


def _plants_in(df) -> list[str]:
    """The plants of a results frame, the nominal one first, then in order of appearance."""
    names = list(dict.fromkeys(df["plant"]))
    return sorted(names, key=lambda n: n != NOMINAL)


Y_FLOOR = -2.0  # suppression below this is drawn at the floor with its value written
_MARKERS = {
    "open_loop": "o",
    "pi_upper": "v",
    "pi_lower": "^",
    "torque_feedback": "s",
    "lqi": "D",
    "lqi_angle_ff": "d",
    "ppo": "P",
    "sac": "X",
}


def _figures(df, preset: str, out: Path, plant: str = NOMINAL) -> list[Path]:
    """The bifurcation figure (nominal plant only: the analysis is of the nominal model) and
    the suppression figure of one preset and plant."""
    import matplotlib

    matplotlib.use("Agg")

    if df.empty:
        return []
    ctrls = ordered_controllers(df["controller"])
    if plant != NOMINAL:
        return _suppression_figure(df, preset, out, plant, ctrls)
    return [bifurcation_figure(df, preset, out)] + _suppression_figure(df, preset, out, plant, ctrls)


def bifurcation_figure(df, preset: str, out: Path) -> Path:
    """``bifurcation_<preset>.png``: one panel per controller, each with the nominal model's
    bifurcation diagram (faded) and, at its exact voltage, every run's steady min and max of
    x3 joined by a bar. Runs beyond the common scale end in a triangle at the panel's edge;
    their range is written under the panel's title."""
    import matplotlib.pyplot as plt

    fig = draw_bifurcation_figure(df, preset)
    p = out / f"bifurcation_{preset}.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


def draw_bifurcation_figure(df, preset: str, diagram=None):
    """The figure of :func:`bifurcation_figure` (``diagram``: the nominal model's to 5 V,
    computed if not given); returns the matplotlib figure."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from drill_env.analysis import bifurcation_diagram
    from drill_env.analysis.plots import plot_bifurcation

    ctrls = ordered_controllers(df["controller"])
    diagram = diagram if diagram is not None else bifurcation_diagram(preset, u_max=5.0)
    tops = [float(np.max([c.x3_max for c in seg.cycles])) for seg in diagram.periodic_segments]
    tops += [float(np.max(b.x3)) for b in diagram.equilibrium_branches]
    y_hi = 1.15 * max(tops + [1.0])
    y_lo = -0.08 * y_hi
    ncol = 4
    nrow = -(-len(ctrls) // ncol)
    fig, axes = plt.subplots(
        nrow, ncol, figsize=(17, 3.9 * nrow + 0.6), sharex=True, sharey=True, squeeze=False
    )
    flat = [a for row in axes for a in row]
    handles: list = []
    for ax, c in zip(flat, ctrls, strict=False):
        plot_bifurcation(diagram, ax, annotate=False, legend=False, lw=1.0, alpha=0.5)
        handles = handles or list(ax.diagram_handles)
        r = df[df["controller"] == c]
        u = r["voltage"].to_numpy(dtype=float)
        hi, lo = r["x3_max"].to_numpy(dtype=float), r["x3_min"].to_numpy(dtype=float)
        col, m = COLORS.get(c, "gray"), _MARKERS.get(c, "o")
        inside_hi, inside_lo = hi <= y_hi, lo >= y_lo
        both = inside_hi & inside_lo  # a run beyond the scale gets no bar across the panel
        ax.vlines(u[both], lo[both], hi[both], color=col, lw=1.0, alpha=0.8, zorder=4)
        ax.plot(u[inside_hi], hi[inside_hi], m, color=col, ms=4.5, mfc="white", zorder=5)
        ax.plot(u[inside_lo], lo[inside_lo], m, color=col, ms=4.5, mfc="white", zorder=5)
        for beyond, y_edge, m_edge in ((~inside_hi, y_hi, "^"), (~inside_lo, y_lo, "v")):
            if beyond.any():  # on the frame, unclipped (an empty unclipped line would stretch
                # the layout to the figure's corner)
                ax.plot(
                    u[beyond], np.full(beyond.sum(), y_edge), m_edge, color=col, ms=6, clip_on=False, zorder=6
                )
        title = c
        off = ~(inside_hi & inside_lo)
        if off.any():
            vs = u[off]
            title += (
                f"\n{int(off.sum())} runs off scale ({vs.min():g}-{vs.max():g} V):"
                f"\nx3 from {lo[off].min():.1f} to {hi[off].max():.1f} rad/s"
            )
        ax.set_title(title, fontsize=9, color=col if c != "open_loop" else "black")
        ax.set_xlabel("")
        ax.set_ylabel("")
    for ax in flat[len(ctrls) :]:
        ax.axis("off")
    for row in axes:
        row[0].set_ylabel("steady min / max of x3 [rad/s]", fontsize=9)
    for ax in axes[-1]:
        ax.set_xlabel("nominal voltage u [V]", fontsize=9)
    for k, ax in enumerate(flat[: len(ctrls)]):
        if k + ncol >= len(ctrls):  # the lowest panel of its column
            ax.tick_params(labelbottom=True)
            ax.set_xlabel("nominal voltage u [V]", fontsize=9)
    ax0 = flat[0]
    ax0.set_ylim(y_lo, y_hi)
    ax0.set_xlim(0.0, 5.1)
    handles = [h for h in handles if "simulation" not in h.get_label()]
    handles += [
        Line2D(
            [],
            [],
            color="0.3",
            marker="o",
            mfc="white",
            ms=4.5,
            lw=1.0,
            label="a run's steady min and max of x3",
        ),
        Line2D(
            [], [], color="0.3", marker="^", ls="none", ms=6, label="run off scale (range under the title)"
        ),
    ]
    ncol_legend = 4
    fig.legend(handles=handles, loc="lower center", fontsize=8, ncol=ncol_legend, frameon=False)
    fig.suptitle(
        f"{preset}: each controller's closed-loop runs (one per seed; steady state: the last "
        f"{EpisodeSettings().window:g} s) on the nominal model's bifurcation diagram (faded)",
        fontsize=11,
    )
    legend_rows = -(-len(handles) // ncol_legend)
    fig.tight_layout(rect=(0, (0.3 + 0.2 * legend_rows) / fig.get_figheight(), 1, 1))
    return fig


def _regime_handles(preset: str) -> list:
    """Legend entries of the regime shading of the suppression figures."""
    from matplotlib.patches import Patch

    present = {name for name, _, _ in _regime_spans(preset)}
    return [
        Patch(color=_REGIME_SHADES[name], alpha=0.15, label=f"nominal model: {REGIMES[name]}")
        for name in ("limit_cycle", "stick_slip")
        if name in present
    ]


_REGIME_SHADES = {"limit_cycle": "tab:orange", "stick_slip": "tab:red"}
FLOOR_BAND = 0.45  # [-] height of the band under the floor where off-scale means are written


def _draw_suppression(ax, df, preset: str, ctrls, *, small: bool = False) -> None:
    """Suppression against voltage of each controller (mean over seeds, seed range as bars),
    every marker at its run's voltage. Means below the floor are drawn on it and written in
    a band beneath it (only when not ``small``)."""
    cyc = df[df["open_loop_amplitude"] > 0]
    for name, lo, hi in _regime_spans(preset):
        if name in _REGIME_SHADES:
            ax.axvspan(lo, hi, color=_REGIME_SHADES[name], alpha=0.15, lw=0, zorder=0)
    floored: list[tuple[float, float, str]] = []
    for c in ctrls:
        r = cyc[cyc["controller"] == c]
        if r.empty:
            continue
        g = r.groupby("voltage")["suppression"]
        v = np.array(sorted(g.groups))
        mean, lo, hi = g.mean().loc[v].to_numpy(), g.min().loc[v].to_numpy(), g.max().loc[v].to_numpy()
        shown = np.maximum(mean, Y_FLOOR)
        ax.errorbar(
            v,
            shown,
            yerr=[shown - np.maximum(lo, Y_FLOOR), np.maximum(hi, Y_FLOOR) - shown],
            fmt=_MARKERS.get(c, "o") + "-",
            color=COLORS.get(c, "gray"),
            mfc="none",
            mew=1.0,
            ms=3 if small else 6,
            lw=0.8 if small else 1,
            capsize=0 if small else 2,
            label=c,
        )
        floored += [(float(vv), float(mm), c) for vv, mm in zip(v, mean, strict=True) if mm < Y_FLOOR]
    ax.axhline(0.0, color="gray", lw=0.8)
    ax.axhline(1.0, color="gray", lw=0.8, ls=":")
    from drill_env.analysis.plots import AMPLIFIER_LIMIT_V

    ax.axvline(AMPLIFIER_LIMIT_V, color="tab:purple", lw=1.0, ls="-.", zorder=1)
    lo_y = (
        min(-0.5, float(np.nanmin(cyc["suppression"])) - 0.05) if cyc["suppression"].notna().any() else -0.5
    )
    bottom = max(lo_y, Y_FLOOR - 0.1)
    if floored and not small:
        bottom = Y_FLOOR - FLOOR_BAND
        ax.axhspan(bottom, Y_FLOOR - 0.04, color="white", zorder=2.5)  # a band clear of lines
        ax.axhline(Y_FLOOR - 0.04, color="0.5", lw=0.6, ls="--", zorder=2.6)
        rows: dict[float, int] = {}
        for vv, mm, c in sorted(floored):
            k = rows.get(vv, 0)
            rows[vv] = k + 1
            ax.annotate(
                f"{mm:.1f}",
                (vv, Y_FLOOR - 0.04),
                xytext=(0, -3 - 9 * k),
                textcoords="offset points",
                fontsize=7,
                color=COLORS.get(c, "gray"),
                ha="center",
                va="top",
                zorder=3,
            )
    ax.set_ylim(bottom, 1.1)
    ax.set_xlim(0.0, 5.1)
    ax.grid(alpha=0.3)


def _suppression_figure(df, preset: str, out: Path, plant: str, ctrls) -> list[Path]:
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, ax = plt.subplots(figsize=(12.5, 5.2))
    _draw_suppression(ax, df, preset, ctrls)
    ax.set_xlabel("nominal voltage u [V]")
    ax.set_ylabel("suppression = 1 - amplitude / open-loop amplitude [-]")
    on = "" if plant == NOMINAL else f" on plant {plant} (reference: the open-loop run on it)"
    ax.set_title(f"{preset}{on}: suppression of the open-loop cycle", fontsize=10)
    handles, _ = ax.get_legend_handles_labels()
    handles = [Line2D([], [], ls="none", label="mean over seeds, bar: min-max:"), *handles]
    handles += [
        Line2D([], [], color="gray", lw=0.8, ls=":", label="1: cycle removed"),
        Line2D([], [], color="gray", lw=0.8, label="0: amplitude as open loop"),
        Line2D([], [], color="tab:purple", lw=1.0, ls="-.", label="amplifier limit 5 V"),
        *_regime_handles(preset),
    ]
    if any(t.get_text() for t in ax.texts):
        handles.append(
            Line2D(
                [],
                [],
                color="0.5",
                lw=0.6,
                ls="--",
                label=f"below {Y_FLOOR:g}: drawn at {Y_FLOOR:g},\nmean written under the dashed line",
            )
        )
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    p = out / (f"suppression_{preset}.png" if plant == NOMINAL else f"suppression_{preset}_{plant}.png")
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return [p]


def _plants_figure(df, preset: str, out: Path, plants: Sequence[str]) -> Path:
    """``suppression_<preset>_plants.png``: the suppression figure of every plant other than
    the nominal one as small multiples (one panel per plant, shared axes)."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    ok = df[(df["preset"] == preset) & (df["error"] == "")]
    ctrls = ordered_controllers(ok["controller"])
    ncol = 4
    nrow = -(-(len(plants) + 1) // ncol)  # one slot for the legend
    fig, axes = plt.subplots(
        nrow, ncol, figsize=(16, 2.6 * nrow + 1.0), sharex=True, sharey=True, squeeze=False
    )
    flat = [a for row in axes for a in row]
    for k, plant in enumerate(plants):
        ax = flat[k]
        _draw_suppression(ax, ok[ok["plant"] == plant], preset, ctrls, small=True)
        ax.set_title(plant, fontsize=9)
        ax.set_ylim(Y_FLOOR - 0.1, 1.1)
        if k % ncol == 0:
            ax.set_ylabel("suppression [-]")
        if k + ncol >= len(plants):  # the lowest panel of its column
            ax.set_xlabel("nominal voltage u [V]")
            ax.tick_params(labelbottom=True)
    for ax in flat[len(plants) :]:
        ax.axis("off")
    handles, _ = flat[0].get_legend_handles_labels()
    handles = [Line2D([], [], ls="none", label="mean over seeds, bar: min-max:"), *handles]
    handles += [
        Line2D([], [], color="gray", lw=0.8, ls=":", label="1: cycle removed"),
        Line2D([], [], color="gray", lw=0.8, label="0: amplitude as open loop"),
        Line2D([], [], color="tab:purple", lw=1.0, ls="-.", label="amplifier limit 5 V"),
        *_regime_handles(preset),
    ]
    fig.suptitle(
        f"{preset}: suppression on each plant, controllers designed on the nominal model "
        f"(reference: the open-loop run on the same plant; means below {Y_FLOOR:g} drawn at {Y_FLOOR:g})",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0, 1, 0.985))
    # after the layout, which would otherwise shrink every panel to the legend's width
    flat[len(plants)].legend(
        handles=handles, loc="upper left", bbox_to_anchor=(0.05, 0.95), fontsize=8, frameon=False, ncol=3
    )
    p = out / f"suppression_{preset}_plants.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


@functools.lru_cache(maxsize=8)
def _regime_spans(preset: str) -> list[tuple[str, float, float]]:
    from drill_env.envs.task import operating_regimes
    from drill_env.params import load_params

    return list(operating_regimes(load_params(preset)).intervals)
