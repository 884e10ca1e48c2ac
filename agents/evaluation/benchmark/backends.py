"""Running a benchmark's grid: in this process, in a local process pool or on Ray, each run
appended to the results file as it finishes, then the report."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drill_env.agents.evaluation.benchmark.grid import BenchmarkConfig, Job
from drill_env.agents.evaluation.benchmark.provenance import (
    PROVENANCE_FILE,
    code_identity,
    session_record,
    write_provenance,
)
from drill_env.agents.evaluation.benchmark.report import RANKING_FILE, REPORT_FIGURES, write_report
from drill_env.agents.evaluation.benchmark.runs import _run_chunk, _worker_init, open_loop_cycles_of, run_job
from drill_env.agents.evaluation.benchmark.store import (
    _done_keys,
    _drop_partial_row,
    _rewrite_sorted,
    _Writer,
    check_resumable,
)
from drill_env.outputs import atomic_write_text, output_lock

BACKENDS = ("process", "sequential", "ray")


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
    code = code_identity()  # the code as the session starts (files may change while it runs)
    cfg_path = out / "benchmark_config.json"
    record = cfg.settings_record()
    if fresh:  # the results and the report made from them (no stale figure of a plant left)
        report = [out / "summary.md"] + [
            f for pattern in REPORT_FIGURES for f in (out.glob(pattern) if out.is_dir() else [])
        ]
        for p in (csv_path, cfg_path, out / PROVENANCE_FILE, out / RANKING_FILE, *report):
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
    done = _done_keys(csv_path)
    all_jobs = cfg.jobs()
    todo = [j for j in all_jobs if j.key not in done]
    if old is not None and not todo and "policies" in old:
        # nothing to run: the report is written again from the rows, and the policies that
        # made them stay those recorded (they need not be here)
        policies, starts = old["policies"], old.get("policy_starts", {})
    else:
        policies, starts = _policies_used(cfg), _policy_starts(cfg)
    full_record = dict(
        record,
        **_design_regimes_record(cfg),
        presets=list(cfg.presets),
        controllers=list(cfg.controllers),
        voltages={p: list(v) for p, v in cfg.voltages.items()},
        seeds=list(cfg.seeds),
        policies=policies,
        policy_starts=starts,
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
        rows_before = total - len(todo)  # an interrupted session is recorded with the rows it wrote
        write_provenance(
            out,
            session_record(
                cfg, rows_run=n_done - rows_before, rows_before=rows_before, backend=backend, code=code
            ),
        )
    missing = {j.key for j in all_jobs} - _rewrite_sorted(csv_path, cfg)
    if missing:  # only if something bypassed the lock
        raise RuntimeError(
            f"{csv_path}: {len(missing)} of {total} runs are missing after the benchmark "
            f"(e.g. {sorted(missing)[0]}); was the file changed by another process?"
        )
    if report:
        write_report(csv_path, out)
    return csv_path


def _design_regimes_record(cfg: BenchmarkConfig) -> dict[str, str]:
    """The design model's regimes in one line (for the report), when there is a design model."""
    if cfg.design_params is None:
        return {}
    from drill_env.agents.evaluation.benchmark.grid import describe_regimes, design_regimes

    try:
        return {"design_regimes": describe_regimes(design_regimes(cfg.design_model()))}
    except (ValueError, RuntimeError) as exc:
        return {"design_regimes": f"not found ({exc})"}


def _policies_used(cfg: BenchmarkConfig) -> dict[str, str]:
    """Which trained policy each learned controller runs per preset (for the report): its
    path (relative to the project root when inside it, else as given) and env id."""
    from drill_env.agents._locations import shown_path
    from drill_env.agents.registry import LEARNED, policy_path

    out = {}
    for c in cfg.controllers:
        if c not in LEARNED:
            continue
        for p in cfg.presets:
            try:
                path = policy_path(c, p, cfg.agents_dir)
                shown = shown_path(path)
                try:
                    from drill_env.agents.evaluation.episodes import env_id_of
                    from drill_env.agents.learning.rl import policy_observation_version

                    shown += f" on {env_id_of(p, policy_observation_version(path))}"
                except ValueError:
                    pass
                out[f"{c}/{p}"] = shown
            except ValueError as exc:
                out[f"{c}/{p}"] = f"missing ({exc})"
    return out


def _policy_starts(cfg: BenchmarkConfig) -> dict[str, str]:
    """How each learned controller's policy per preset started (from scratch, clone of X,
    residual on X, ...; :func:`drill_env.agents.learning.cards.policy_start`), read from the
    ``config.yaml`` beside it; a policy without one is left out."""
    from drill_env.agents.learning.cards import policy_start
    from drill_env.agents.registry import LEARNED, policy_path
    from drill_env.yamlio import load_yaml

    out = {}
    for c in cfg.controllers:
        if c not in LEARNED:
            continue
        for p in cfg.presets:
            try:
                config = policy_path(c, p, cfg.agents_dir).parent / "config.yaml"
            except ValueError:
                continue
            if config.is_file():
                out[f"{c}/{p}"] = policy_start(load_yaml(config, what="policy config") or {})
    return out


def _run_process_pool(todo: list[Job], cfg: BenchmarkConfig, workers: int, finish) -> None:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # Small chunks: the pool stays busy and an interruption loses little.
    size = max(1, min(8, len(todo) // (4 * workers) or 1))
    ctx = mp.get_context("spawn")  # torch and numba threads do not survive fork safely
    cycles = open_loop_cycles_of(todo, cfg)
    pool = ProcessPoolExecutor(
        max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=(cycles,)
    )
    try:
        pending = {pool.submit(_run_chunk, chunk, cfg) for chunk in _chunks(todo, size)}
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                for row in fut.result():
                    finish(row)
    except BaseException:
        # interrupted: what is written stays written; neither the queued nor the running runs
        # are waited for (they are run again on resume)
        from drill_env.interrupts import stop_pool

        stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def _run_ray(todo: list[Job], cfg: BenchmarkConfig, workers: int | None, address: str | None, finish) -> None:
    from drill_env.ray_cluster import ray_cluster

    with ray_cluster(workers, address) as ray:
        remote = ray.remote(num_cpus=1)(_run_chunk)
        size = max(1, min(8, len(todo) // (4 * (workers or 2)) or 1))
        cfg_ref = ray.put(cfg)
        pending = [remote.remote(chunk, cfg_ref) for chunk in _chunks(todo, size)]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for row in ray.get(ready[0]):
                finish(row)
