"""The short table each results page opens with, computed from the committed files.

Before the sources are read, this writes ``_generated/results/headline_<page>.md``: one
small Markdown table per results page, read from the CSV and JSON files under ``results/``
(never typed by hand), so that a page starts with a figure and these few numbers and a
regenerated result shows on the next build. A result file that is missing or lacks a column
stops the build with the file's name (the build treats warnings as errors).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

CYCLES = (("limit_cycle", "Hopf"), ("stick_slip", "stick-slip"))
PRESETS = (("brake", "with brake"), ("no_brake", "without brake"))


def _suppression(values) -> str:  # noqa: ANN001
    """``mean (worst)`` to three places, with no "-0.000"."""

    def fmt(x: float) -> str:
        text = f"{x:.3f}"
        return "0.000" if text == "-0.000" else text

    return f"{fmt(values.mean())} ({fmt(values.min())})" if len(values) else "-"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _suppression_by_controller(df, source: str, worst_over: str) -> str:  # noqa: ANN001
    """Mean (worst) suppression of each controller in each preset's cycle regimes."""
    df = df[df["error"].isna()] if "error" in df else df
    controllers = list(dict.fromkeys(df["controller"]))
    cols = [
        (p, r) for p, _ in PRESETS for r, _ in CYCLES if ((df["preset"] == p) & (df["regime"] == r)).any()
    ]
    header = ["controller"] + [f"{dict(PRESETS)[p]}: {dict(CYCLES)[r]}" for p, r in cols]
    rows = []
    for c in controllers:
        row = [f"`{c}`"]
        for p, r in cols:
            s = df[(df["controller"] == c) & (df["preset"] == p) & (df["regime"] == r)]["suppression"]
            row.append(_suppression(s))
        rows.append(row)
    note = (
        f"*Suppression of the cycle the analysis predicts: mean over {worst_over} (worst run in "
        f"brackets); 1 removes it, 0 is open loop ({source}).*\n\n"
    )
    return note + _table(header, rows)


def _csv(results: Path, *folders: str):  # noqa: ANN202
    import pandas as pd

    return pd.concat([pd.read_csv(results / f / "benchmark.csv") for f in folders], ignore_index=True)


def benchmark(results: Path) -> str:
    return _suppression_by_controller(
        _csv(results, "benchmark"), "`benchmark/benchmark.csv`", "the runs of the grid"
    )


def plant_family(results: Path) -> str:
    return _suppression_by_controller(
        _csv(results, "plant_family"), "`plant_family/benchmark.csv`", "the runs on all plants of the family"
    )


def robust_rl(results: Path) -> str:
    return _suppression_by_controller(
        _csv(results, "robust_rl/brake", "robust_rl/no_brake"),
        "`robust_rl/brake/`, `robust_rl/no_brake/`",
        "the runs on all plants of the family",
    )


def discrepancy(results: Path) -> str:
    s = json.loads((results / "discrepancy" / "study.json").read_text(encoding="utf-8"))["summary"]
    rows = [
        ["datasets", f"{s['n_datasets']}"],
        ["right verdict", f"{100 * s['accuracy']:.1f} %"],
        ["false discoveries (an effect named that is not there)", f"{s['false_discoveries']}"],
        ["false alarms (no effect, yet one named)", f"{s['false_alarms']} of {s['datasets_without_effect']}"],
        ["both effects named, where two are hidden", f"{100 * s['two_effects_both_named']:.1f} %"],
        ["parameters inside their 95 % intervals", f"{100 * s['coverage_per_parameter']:.1f} %"],
        ["datasets that failed", f"{s['errors']}"],
    ]
    return "*The hidden-effect study (`discrepancy/study.json`).*\n\n" + _table(["", "study"], rows)


def sim_to_real(results: Path) -> str:
    import pandas as pd

    df = pd.read_csv(results / "sim_to_real" / "results.csv")
    df = df[df["regime"].isin([r for r, _ in CYCLES])]
    rows = []
    for c in dict.fromkeys(df["controller"]):
        row = [f"`{c}`"]
        for design in ("nominal", "corrected"):
            s = df[(df["controller"] == c) & (df["design"].isin([design, "-"]))]["suppression"]
            row.append(_suppression(s))
        rows.append(row)
    note = "*Suppression on the truth plant, mean over its cycle runs (worst in brackets), designed on the nominal and on the corrected model (`sim_to_real/results.csv`).*\n\n"
    return note + _table(
        ["controller", "designed on the nominal model", "designed on the corrected model"], rows
    )


def training(results: Path) -> str:
    """Per learner and rig: the seeds that reached the target check, the median and the worst
    training time to it, on the clock the study counted (wall or training-process CPU seconds)."""
    t = json.loads((results / "training" / "time_to_policy.json").read_text(encoding="utf-8"))
    rows = []
    clocks = set()
    for s in t["summary"]:
        clock = s.get("clock", "wall")
        clocks.add(clock)
        key = "time_to_target_s" if clock == "wall" else "cpu_to_target_s"
        times = [x for x in s.get(key, []) if x is not None]
        median = s.get("median_time_to_target_s" if clock == "wall" else "median_cpu_to_target_s")
        worst = max(times) if times and len(times) == len(s["seeds"]) else None
        rows.append(
            [
                f"{s['algo']}",
                dict(PRESETS).get(s["preset"], s["preset"]),
                f"{s['reached']} of {len(s['seeds'])}",
                f"{median:.0f} s" if median is not None else "- (half or more missed)",
                f"{worst:.0f} s"
                if worst is not None
                else ("-" if not times else f"- (the slowest that met it: {max(times):.0f} s)"),
            ]
        )
    unit = " and ".join("training CPU" if c == "cpu" else "training wall" for c in sorted(clocks))
    note = (
        f"*From scratch: seeds that reached the target and the time to it in {unit} seconds, "
        "the checks excluded (`training/time_to_policy.json`).*\n\n"
    )
    return note + _table(["learner", "rig", "seeds that reached it", "median time", "worst time"], rows)


def leaderboard(results: Path) -> str:
    """Per committed ranking: the leader, its mean suppression and interval, and how many pairs
    of the controllers at 0.99 or more the paired intervals resolve."""
    rows = []
    for folder in ("benchmark", "plant_family"):
        rec = json.loads((results / folder / "ranking.json").read_text(encoding="utf-8"))
        for rk in rec["rankings"]:
            lead = rk["scores"][0]
            score = {r["controller"]: r["score"] for r in rk["scores"]}
            top = [q for q in rk["pairs"] if min(score[q["a"]], score[q["b"]]) >= 0.99]
            rows.append(
                [
                    f"`{folder}` {rk['key']}",
                    lead["controller"],
                    f"{lead['score']:.4f} [{lead['low']:.4f}, {lead['high']:.4f}]",
                    str(sum(v >= 0.99 for v in score.values())),
                    f"{sum(q['resolved'] for q in top)} of {len(top)}",
                ]
            )
    suite_path = results / "scenarios" / "ranking.json"
    if suite_path.is_file():
        rec = json.loads(suite_path.read_text(encoding="utf-8"))
        rk = next(r for r in rec["rankings"] if r["key"] == "suite")
        lead = rk["scores"][0]
        top = rec.get("nominal_leaders") or {}
        rows.append(
            [
                "`scenarios` suite score",
                lead["controller"],
                f"{lead['score']:.4f} [{lead['low']:.4f}, {lead['high']:.4f}]",
                f"{len(top.get('controllers', {}))} (nominal)" if top else "-",
                f"{top['resolved']} of {top['n_pairs']}" if top else "-",
            ]
        )
    note = (
        "*From `benchmark/ranking.json`, `plant_family/ranking.json` and `scenarios/ranking.json` (95 % paired "
        "BCa intervals; the suite row: the suite score, and the nominal benchmark's leaders at 0.99+ told "
        "apart by the suite).*\n\n"
    )
    header = [
        "ranking",
        "leader",
        "its score [interval]",
        "controllers at 0.99+",
        "their pairs resolved",
    ]
    return note + _table(header, rows)


def bifurcation(results: Path) -> str:
    """The points A-F of each committed diagram: voltage and type."""
    rows = []
    for folder, label in (
        ("no_brake", "without brake"),
        ("brake", "with brake"),
        ("brake_extended", "with brake, beyond 5 V"),
    ):
        rec = json.loads((results / "bifurcation" / folder / "bifurcation.json").read_text(encoding="utf-8"))
        for name, point in sorted(rec["points"].items()):
            rows.append([label, name, f"{point['u']:.3f}", point["type"].replace("_", " ")])
    note = "*The points of each diagram, found on the exact nonsmooth flow (`bifurcation/*/bifurcation.json`).*\n\n"
    return note + _table(["diagram", "point", "voltage [V]", "type"], rows)


def rig_loop(results: Path) -> str:
    """What the loop run measured: suppression and tracking as the benchmark computes them, and its timing."""
    r = json.loads((results / "rig_loop" / "result.json").read_text(encoding="utf-8"))
    m, t = r["measured"], r["timing"]
    rows = [
        [
            "controller, set point",
            f"`{r['controller']}`, {r['nominal_voltage']:g} V ({r['regime'].replace('_', '-')})",
        ],
        ["suppression", f"{m['suppression']:.3f}"],
        ["RMS speed error [rad/s]", f"{m['rms_error']:.3f}"],
        ["control periods", f"{t['periods']} of {t['period_ms']:g} ms"],
        ["period jitter: std / max [ms]", f"{t['jitter_std_ms']:.1f} / {t['jitter_max_ms']:.1f}"],
        ["missed deadlines", f"{t['missed_deadlines']}"],
        ["ended by", f"{r['ended_by']}" + (f" ({r['trip']})" if r.get("trip") else "")],
    ]
    return "*The run of `rig_loop/result.json`.*\n\n" + _table(["", "measured"], rows)


def scenarios(results: Path) -> str:
    """Each controller's suite score with its paired interval and the ranks its resolved differences allow."""
    rec = json.loads((results / "scenarios" / "ranking.json").read_text(encoding="utf-8"))
    rk = next(r for r in rec["rankings"] if r["key"] == "suite")
    rows = [
        [
            f"`{q['controller']}`",
            f"{q['score']:.3f} [{q['low']:.3f}, {q['high']:.3f}]",
            f"{q['best_rank']}"
            if q["best_rank"] == q["worst_rank"]
            else f"{q['best_rank']}-{q['worst_rank']}",
        ]
        for q in rk["scores"]
    ]
    note = (
        f"*Suite score (mean over {rk['n_units']} paired scenario x preset x seed units; 95 % {rk['method']} "
        "interval) and the ranks its resolved differences allow (`scenarios/ranking.json`).*\n\n"
    )
    return note + _table(["controller", "suite score [interval]", "rank"], rows)


def identify(results: Path) -> str:
    """The worked example: the hidden effect, how close the identified parameters came to the
    truth, and the controllers designed on the identified model on the truth plant."""
    import yaml

    base = results / "identify"
    truth = yaml.safe_load((base / "truth" / "rig.yaml").read_text(encoding="utf-8"))
    answer = json.loads((base / "truth" / "answer.json").read_text(encoding="utf-8"))
    ident = json.loads((base / "identified" / "identification.json").read_text(encoding="utf-8"))
    fitted = {
        k: v
        for k, v in ident["parameters"].items()
        if v.get("identified") and k != ident["scale"]["parameter"]
    }
    errors = {k: v["value"] / truth[k] - 1.0 for k, v in fitted.items() if truth.get(k)}
    inside = [k for k, v in fitted.items() if v["ci95"][0] <= truth[k] <= v["ci95"][1]]
    worst_param = max(errors, key=lambda k: abs(errors[k]))
    rows = [
        ["effect hidden in the truth", f"`{answer['effect']}` (magnitude {answer['magnitude']:g})"],
        [
            "parameters within 3 % of the truth",
            f"{sum(abs(e) <= 0.03 for e in errors.values())} of {len(errors)}",
        ],
        ["largest error", f"`{worst_param}` {100 * errors[worst_param]:+.1f} %"],
        ["truth inside the 95 % interval", f"{len(inside)} of {len(fitted)}"],
    ]
    runs = json.loads((base / "controllers_on_truth.json").read_text(encoding="utf-8"))
    for c in dict.fromkeys(r["controller"] for r in runs):
        worst = min(r["suppression"] for r in runs if r["controller"] == c)
        rows.append([f"`{c}` on the truth, worst suppression", f"{worst:.3f}"])
    note = "*The worked example (`identify/truth/`, `identify/identified/identification.json`, `identify/controllers_on_truth.json`).*\n\n"
    return note + _table(["", "worked example"], rows)


HEADLINES: dict[str, Callable[[Path], str]] = {
    "leaderboard": leaderboard,
    "benchmark": benchmark,
    "plant_family": plant_family,
    "robust_rl": robust_rl,
    "discrepancy": discrepancy,
    "sim_to_real": sim_to_real,
    "training": training,
    "bifurcation": bifurcation,
    "rig_loop": rig_loop,
    "scenarios": scenarios,
    "identify": identify,
}


def write_headlines(app) -> None:  # noqa: ANN001 (Sphinx application)
    src = Path(app.srcdir)
    results = src.parent / "results"
    out = src / "_generated" / "results"
    out.mkdir(parents=True, exist_ok=True)
    for page, make in HEADLINES.items():
        try:
            text = make(results)
        except (OSError, KeyError, ValueError) as exc:
            raise RuntimeError(f"the headline table of docs/results/{page}.md: {exc!r}") from exc
        path = out / f"headline_{page}.md"
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")


def setup(app):  # noqa: ANN001, ANN201
    app.connect("builder-inited", write_headlines)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
