"""The results file ``benchmark.csv``: its columns, appending each finished run, resuming an
interrupted benchmark (the settings in ``benchmark_config.json`` must match) and the final
rewrite in grid order."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.agents.evaluation.benchmark.grid import BenchmarkConfig
from drill_env.agents.evaluation.episodes import IDENTIFIED_SPEED, METRIC_COLUMNS
from drill_env.agents.evaluation.plants import NOMINAL
from drill_env.agents.registry import CONTROLLERS
from drill_env.outputs import atomic_file, keep_on_error, open_append, refuse_link, refuse_links
from drill_env.params import PRESETS

COLUMNS = METRIC_COLUMNS[:2] + ("plant",) + METRIC_COLUMNS[2:] + ("error",)
KEY = ("controller", "preset", "plant", "voltage", "seed")


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

    text = ("controller", "preset", "plant", "regime", "plant_open_loop_regime", "error")
    df = pd.read_csv(path, dtype={c: object for c in text})
    if "plant" not in df.columns:  # a CSV from before plants: every run on the nominal model
        df.insert(2, "plant", NOMINAL)
    if "x3_peak_abs" not in df.columns and {"x3_min", "x3_max", "preset"} <= set(df.columns):
        # a CSV written before these columns existed: the peak of its scoring window
        df["x3_peak_abs"] = np.maximum(df["x3_min"].abs(), df["x3_max"].abs())
        limit = df["preset"].map(lambda p: IDENTIFIED_SPEED.get(str(p), math.inf)).astype(float)
        df["beyond_identified_range"] = df["x3_peak_abs"] > limit
    if "stalled" not in df.columns and {"stick_fraction", "mean_speed", "target_speed"} <= set(df.columns):
        # a CSV written before the stalled rule: the rule applied to its columns
        from drill_env.agents.evaluation.episodes import is_stalled

        df["stalled"] = [
            is_stalled(f, m, w)
            for f, m, w in zip(df["stick_fraction"], df["mean_speed"], df["target_speed"], strict=True)
        ]
    if "plant_open_loop_regime" not in df.columns and "regime" in df.columns:
        df["plant_open_loop_regime"] = ""  # not recorded then
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; expected {list(COLUMNS)}")
    for c in text:
        df[c] = df[c].where(df[c].notna(), "").astype(str)
    flags = ("beyond_identified_range", "stalled")
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
    refuse_links(out, ("benchmark.csv", "benchmark_config.json", "summary.md"), "out:")
    if not (cfg_path.is_file() and csv_path.is_file()):
        return None
    record = cfg.settings_record()
    old = _read_settings(cfg_path)
    if old.get("episode") != json.loads(json.dumps(record["episode"])):
        raise ValueError(
            f"out: {out} holds a benchmark with other episode settings ({old.get('episode')}); "
            "use another directory or --fresh to start over"
        )
    if old.get("design_model") != json.loads(json.dumps(record.get("design_model"))):
        raise ValueError(
            f"out: {out} holds a benchmark designed on another model; use another directory or "
            "--fresh to start over"
        )
    own = old.get("custom_controllers") or {}
    for label, spec in (record.get("custom_controllers") or {}).items():
        if label in own and own[label] != spec:
            raise ValueError(
                f"--controller {spec!r}: {out} holds rows of {label!r} made by {own[label]!r}; give this one "
                "another label (LABEL=SPEC), use another directory or --fresh to start over"
            )
    before = {q["name"]: q for q in old.get("plants", [])}
    for q in json.loads(json.dumps(record.get("plants", []))):
        if q["name"] in before and before[q["name"]] != q:
            raise ValueError(
                f"plant: {q['name']!r} in {out} was run with other parameters; rename the plant "
                "file, use another directory or --fresh to start over"
            )
    _done_keys(csv_path)
    _check_same_grid(cfg, out, old, csv_path)
    return old


def runs_missing(cfg: BenchmarkConfig, out_dir: str | Path) -> int:
    """How many runs of ``cfg``'s grid the results file in ``out_dir`` lacks (all of them
    without one); call it after :func:`check_resumable`. Zero: resuming runs nothing, it only
    writes the report and the figures again from the rows."""
    done = _done_keys(Path(out_dir) / "benchmark.csv")
    return sum(1 for j in cfg.jobs() if j.key not in done)


def _check_same_grid(cfg: BenchmarkConfig, out: Path, old: Mapping[str, Any], csv_path: Path) -> None:
    """Refuse to resume a benchmark of another grid: every run of the one in ``out`` (its
    recorded grid and every row of its CSV) must be a run of ``cfg``, so that the results and
    the report never mix grids or describe a part of what the folder holds. A grid that grows
    (more controllers, voltages, seeds) resumes."""
    new = {j.key for j in cfg.jobs()}
    before: set[tuple[str, str, str, float, int]] = set()
    if all(k in old for k in ("presets", "controllers", "voltages", "seeds")):
        plants = [str(q.get("name")) for q in old.get("plant_notes", [])] or [NOMINAL]
        before |= {
            (str(c), str(p), q, round(float(v), 9), int(s))
            for p in old["presets"]
            for q in plants
            for v in old["voltages"].get(p, [])
            for s in old["seeds"]
            for c in old["controllers"]
        }
    data = csv_path.read_bytes()
    source: Path | io.BytesIO = csv_path
    if data and not data.endswith(b"\n"):
        source = io.BytesIO(data[: data.rfind(b"\n") + 1])
    before |= {_key_of_row(r) for r in load_results(source).to_dict("records")}
    extra = before - new
    if not extra:
        return
    diffs = []
    # the key's fields: controller, preset, plant, voltage, seed
    for i, (name, here) in enumerate(
        (
            ("controllers", set(cfg.controllers)),
            ("presets", set(cfg.presets)),
            ("plants", {q.name for q in cfg.plants}),
        )
    ):
        missing = sorted({k[i] for k in extra} - here)
        if missing:
            diffs.append(f"{name} {missing[:6]}")
    volts = sorted(
        {(k[1], k[3]) for k in extra if k[1] in cfg.voltages}
        - {(p, round(v, 9)) for p, vs in cfg.voltages.items() for v in vs}
    )
    if volts:
        diffs.append(f"voltages {[f'{p} {v:g} V' for p, v in volts[:6]]}")
    seeds = sorted({k[4] for k in extra} - set(cfg.seeds))
    if seeds:
        diffs.append(f"seeds {seeds[:6]}")
    raise ValueError(
        f"out: {out} holds a benchmark of another grid, with {'; '.join(diffs) or 'other runs'} that this one "
        f"lacks ({len(extra)} runs); a benchmark resumes only its own grid (or a larger one): run it with the "
        "grid of its benchmark_config.json, write elsewhere, or --fresh to start over"
    )


def _drop_partial_row(csv_path: Path) -> None:
    """Cut a last row that an interrupted run left without its line end (it is run again)."""
    if not csv_path.is_file():
        return
    data = csv_path.read_bytes()
    if not data or data.endswith(b"\n"):
        return
    keep = data.rfind(b"\n") + 1
    refuse_link(csv_path)
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
        if new:  # the header first, whole: a kill never leaves an empty or headless file
            with atomic_file(path, "w", newline="") as f:
                csv.DictWriter(f, fieldnames=list(COLUMNS)).writeheader()
        keep_on_error(path)  # the runs finished so far outlive a full disk: the same command resumes
        self.f = open_append(path, newline="")  # never through a link out of the folder
        self.w = csv.DictWriter(self.f, fieldnames=list(COLUMNS))

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
