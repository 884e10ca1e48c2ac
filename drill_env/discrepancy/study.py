"""The hidden-effect study and the paper's case.

:func:`run_study` makes many synthetic datasets (every effect of the library, no effect,
and an effect outside the library), runs the decision part of the workflow on each
without ever seeing the answer, and tabulates

* the confusion matrix (true effect x verdict) at magnitudes drawn from the documented
  detectable ranges and the default noise;
* the detection rate against the magnitude (multiples of the range's lower end);
* the detection rate against the angle noise (at the lower end of each range).

:func:`paper_case` builds data made to look like the paper's low-voltage runs (brake,
1 kHz, constant 0.2-1.0 V plus identification runs, position-dependent friction at the
lower disk) and runs the full workflow with the 0.2 V and 0.5 V runs held out.

Both hold their output folder (:func:`drill_env.outputs.output_lock`) while they write and
replace each file whole; the counts are checked before anything is written.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from drill_env.discrepancy.dataset import MeasuredDataset
from drill_env.discrepancy.synth import HIDDEN_EFFECTS, SynthConfig, make_dataset
from drill_env.discrepancy.workflow import RESULT_EFFECTS, analyse
from drill_env.outputs import atomic_file, atomic_write_text, output_lock

__all__ = ["run_study", "paper_case", "expected_verdict", "check_seed_count", "MAX_SEEDS"]

MAGNITUDE_FACTORS = (0.1, 0.3, 1.0)
NOISE_LEVELS = (0.0, 1e-3, 3e-3, 1e-2)  # [rad]
# The confusion matrix, the magnitude sweep and the noise sweep draw their datasets from the
# seeds 1000+s, 2000+s and 3000+s: at most 1000 seeds each keeps the three parts apart.
SEED_BLOCK = 1000
MAX_SEEDS = SEED_BLOCK


def check_seed_count(name: str, value: object) -> None:
    """ValueError unless ``value`` is a number of seeds the study can use (1 to MAX_SEEDS)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= MAX_SEEDS:
        raise ValueError(f"{name} must be an integer from 1 to {MAX_SEEDS}, got {value!r}")


def expected_verdict(effect: str) -> str:
    if effect == "external_torque":
        return "unexplained"
    return effect


def _one(effect: str, seed: int, magnitude, cfg: SynthConfig, bootstrap: int) -> dict:
    from drill_env.discrepancy.decide import DecisionRule

    syn = make_dataset(effect, seed=seed, magnitude=magnitude, config=cfg)
    ds = MeasuredDataset(
        preset=cfg.preset, encoder_counts_per_rev=cfg.encoder_counts_per_rev, runs=tuple(syn.runs)
    )
    t = time.perf_counter()
    res = analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=bootstrap), seed=seed)
    return {
        "effect": effect,
        "seed": seed,
        "magnitude": syn.answer["magnitude"],
        "noise": cfg.angle_noise_std,
        "verdict": res.effect,
        "confidence": res.decision.confidence,
        "correct": res.effect == expected_verdict(effect),
        "seconds": time.perf_counter() - t,
    }


def run_study(
    out: str | Path,
    *,
    seeds: int = 5,
    sweep_seeds: int = 3,
    base: SynthConfig | None = None,
    bootstrap: int = 100,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Run the study and write ``study.json``, ``confusion.md``, and the figures to ``out``.

    ``seeds`` and ``sweep_seeds`` (datasets per effect and per sweep point) are 1 to
    :data:`MAX_SEEDS`; nothing is written unless they are.
    """
    check_seed_count("seeds", seeds)
    check_seed_count("sweep_seeds", sweep_seeds)
    if isinstance(bootstrap, bool) or not isinstance(bootstrap, (int, np.integer)) or bootstrap < 0:
        raise ValueError(f"bootstrap must be an integer >= 0, got {bootstrap!r}")
    out = Path(out)
    with output_lock(out, "discrepancy-study"):
        return _run_study(out, seeds, sweep_seeds, base or SynthConfig(), bootstrap, progress)


def _run_study(out: Path, seeds: int, sweep_seeds: int, base: SynthConfig, bootstrap: int, progress) -> dict:
    effects = [e for e in HIDDEN_EFFECTS]
    jobs: list[tuple[str, str, int, float | None, SynthConfig]] = []
    for e in effects:
        for s in range(seeds):
            jobs.append(("confusion", e, SEED_BLOCK + s, None, base))
    for e in effects:
        if e == "none":
            continue
        low = HIDDEN_EFFECTS[e].low
        for f in MAGNITUDE_FACTORS:
            for s in range(sweep_seeds):
                jobs.append((f"magnitude:{f}", e, 2 * SEED_BLOCK + s, low * f, base))
    for e in effects:
        low = HIDDEN_EFFECTS[e].low if e != "none" else None
        for nz in NOISE_LEVELS:
            for s in range(sweep_seeds):
                jobs.append((f"noise:{nz}", e, 3 * SEED_BLOCK + s, low, replace(base, angle_noise_std=nz)))
    rows = []
    for i, (part, e, seed, mag, cfg) in enumerate(jobs):
        row = _one(e, seed, mag, cfg, bootstrap)
        row["part"] = part
        rows.append(row)
        if progress:
            progress(i + 1, len(jobs))
    summary = _summarise(rows, effects)
    atomic_write_text(out / "study.json", json.dumps({"rows": rows, "summary": summary}, indent=2) + "\n")
    _write_markdown(out, rows, summary, effects, base, seeds, sweep_seeds)
    _plot(out, summary, effects)
    return summary


def _summarise(rows, effects):
    conf = {e: {v: 0 for v in RESULT_EFFECTS} for e in effects}
    for r in rows:
        if r["part"] == "confusion":
            conf[r["effect"]][r["verdict"]] += 1
    mag = {e: {} for e in effects if e != "none"}
    noise = {e: {} for e in effects}
    for r in rows:
        if r["part"].startswith("magnitude:"):
            f = float(r["part"].split(":")[1])
            mag[r["effect"]].setdefault(f, []).append(r["correct"])
        elif r["part"].startswith("noise:"):
            nz = float(r["part"].split(":")[1])
            noise[r["effect"]].setdefault(nz, []).append(r["correct"])
    rate = lambda d: {str(k): float(np.mean(v)) for k, v in sorted(d.items())}  # noqa: E731
    n_conf = sum(sum(v.values()) for v in conf.values())
    correct = sum(conf[e].get(expected_verdict(e), 0) for e in effects)
    return {
        "confusion": conf,
        "confusion_accuracy": correct / max(n_conf, 1),
        "detection_vs_magnitude": {e: rate(v) for e, v in mag.items()},
        "detection_vs_noise": {e: rate(v) for e, v in noise.items()},
        "mean_seconds_per_dataset": float(np.mean([r["seconds"] for r in rows])),
    }


def _write_markdown(out, rows, summary, effects, base, seeds, sweep_seeds):
    verdicts = list(RESULT_EFFECTS)
    short = {v: v.replace("position_friction_", "pos_").replace("friction_", "fr_") for v in verdicts}
    lines = [
        "# Hidden-effect study",
        "",
        "Regenerate with `drill-env discrepancy-study --out results/discrepancy` (the workflow never sees the "
        "answer; each dataset is made by `drill-env synth` with the same defaults: brake preset, constant "
        f"runs at {', '.join(f'{v:g}' for v in base.voltages)} V and {base.random_runs} quasi-random runs, "
        f"{base.duration_s:g} s each at {base.sample_rate_hz:g} Hz, {base.encoder_counts_per_rev} counts/rev, "
        f"angle noise {base.angle_noise_std:g} rad unless varied).",
        "",
        f"## Confusion matrix ({seeds} seeds per effect, magnitudes log-uniform in the detectable range)",
        "",
        f"Accuracy: {summary['confusion_accuracy']:.1%}. Rows: truth; columns: verdict "
        "(external_torque, outside the library, should give `unexplained`).",
        "",
        "| truth \\ verdict | " + " | ".join(short[v] for v in verdicts) + " |",
        "|---|" + "---|" * len(verdicts),
    ]
    for e in effects:
        lines.append(f"| {e} | " + " | ".join(str(summary["confusion"][e][v]) for v in verdicts) + " |")
    lines += ["", "## Detectable ranges", "", "| effect | magnitude | range |", "|---|---|---|"]
    for e in effects:
        spec = HIDDEN_EFFECTS[e]
        if e != "none":
            lines.append(f"| {e} | {spec.magnitude_meaning} | [{spec.low:g}, {spec.high:g}] |")
    lines += [
        "",
        f"## Detection rate against magnitude ({sweep_seeds} seeds; magnitude = factor x lower end of the range)",
        "",
        "| effect | " + " | ".join(f"x{f:g}" for f in MAGNITUDE_FACTORS) + " |",
        "|---|" + "---|" * len(MAGNITUDE_FACTORS),
    ]
    for e, d in summary["detection_vs_magnitude"].items():
        lines.append(
            f"| {e} | "
            + " | ".join(f"{d.get(str(float(f)), float('nan')):.2f}" for f in MAGNITUDE_FACTORS)
            + " |"
        )
    lines += [
        "",
        f"## Detection rate against angle noise ({sweep_seeds} seeds; magnitude at the lower end of the range; "
        "`none` counts a correct `none`)",
        "",
        "| effect | " + " | ".join(f"{n:g} rad" for n in NOISE_LEVELS) + " |",
        "|---|" + "---|" * len(NOISE_LEVELS),
    ]
    for e, d in summary["detection_vs_noise"].items():
        lines.append(
            f"| {e} | " + " | ".join(f"{d.get(str(float(n)), float('nan')):.2f}" for n in NOISE_LEVELS) + " |"
        )
    wrong = [r for r in rows if not r["correct"]]
    lines += ["", f"## Misclassified datasets ({len(wrong)} of {len(rows)})", ""]
    if wrong:
        lines += [
            "| part | truth | magnitude | noise [rad] | seed | verdict | confidence |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in wrong:
            lines.append(
                f"| {r['part']} | {r['effect']} | {r['magnitude']:.4g} | {r['noise']:g} | {r['seed']} | "
                f"{r['verdict']} | {r['confidence']:.2f} |"
            )
    lines += [
        "",
        f"Mean time of the decision per dataset: {summary['mean_seconds_per_dataset']:.2f} s.",
        "",
        "![detection](detection.png)",
        "",
    ]
    atomic_write_text(out / "confusion.md", "\n".join(lines))


def _plot(out, summary, effects):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    # Many curves sit on 1.0: distinct markers, dash patterns and marker sizes keep each
    # visible where they coincide (values are drawn as they are, never offset).
    markers = ("o", "s", "^", "v", "D", "P", "X", "*", "h")
    dashes = ("-", "--", "-.", ":")
    styles = {e: (markers[i % len(markers)], dashes[i % len(dashes)]) for i, e in enumerate(effects)}
    sizes = {e: 9 - 0.6 * i for i, e in enumerate(effects)}
    for ax, key in zip(axes, ("detection_vs_magnitude", "detection_vs_noise"), strict=True):
        for e, d in summary[key].items():
            xs = [max(float(k), 1e-4) if key == "detection_vs_noise" else float(k) for k in d]
            m, ls = styles.get(e, ("o", "-"))
            ax.plot(
                xs, list(d.values()), marker=m, ls=ls, ms=sizes.get(e, 5), mfc="none", alpha=0.85, label=e
            )
        ax.set_xscale("log")
        ax.set_ylim(-0.05, 1.08)
        ax.grid(alpha=0.3)
    axes[0].set_title("Detection against the effect's magnitude", fontsize=10)
    axes[0].set_xlabel("magnitude / lower end of the detectable range [-]")
    axes[0].set_ylabel("detection rate (share of datasets named right) [-]")
    axes[1].set_title("Detection against the encoder's added angle noise", fontsize=10)
    axes[1].set_xlabel("angle noise standard deviation [rad] (none drawn at 1e-4)")
    axes[1].legend(fontsize=7, title="true effect", title_fontsize=7, loc="lower left")
    fig.suptitle("Hidden-effect study: how often the workflow names the true effect", fontsize=11)
    fig.tight_layout()
    with atomic_file(out / "detection.png", "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)


PAPER_CASE = SynthConfig(
    preset="brake",
    voltages=(0.2, 0.5, 0.7, 1.0),
    random_runs=3,
    duration_s=300.0,
    pre_roll_s=60.0,
    sample_rate_hz=1000.0,
    encoder_counts_per_rev=2000,
    angle_noise_std=1e-3,
)


def paper_case(
    out: str | Path, *, seed: int = 4, magnitude: float = 0.12, data_dir: str | Path | None = None
) -> dict:
    """The paper's Sec. 4.1 case: position-dependent friction at the lower disk, seen at 0.2 and 0.5 V.

    Writes the data to ``data_dir`` (default: a temporary folder, the runs are large), the
    answer to ``out/answer.json`` and the workflow's output to ``out/analysis`` (0.2 V and
    0.5 V runs held out), plus ``spectra_0.2_0.5V.png`` and ``paper_case.md``.
    """
    import tempfile

    if data_dir is None:
        with tempfile.TemporaryDirectory() as tmp:
            return paper_case(out, seed=seed, magnitude=magnitude, data_dir=Path(tmp) / "data")
    out = Path(out)
    with output_lock(out, "discrepancy-study (paper's case)"):
        return _paper_case(out, seed, magnitude, Path(data_dir))


def _paper_case(out: Path, seed: int, magnitude: float, data_dir: Path) -> dict:
    from drill_env.discrepancy.report import plot_spectra
    from drill_env.discrepancy.synth import write_synthetic
    from drill_env.discrepancy.workflow import run_discrepancy

    syn = make_dataset("position_friction_lower", seed=seed, magnitude=magnitude, config=PAPER_CASE)
    write_synthetic(syn, data_dir, out / "answer.json", preset=PAPER_CASE.preset)
    held = [r.name for r in syn.runs if r.is_constant_voltage and r.voltage in (0.2, 0.5)]
    res = run_discrepancy(data_dir, out / "analysis", heldout=held)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, name in zip(axes, held, strict=False):
        run = next(r for r in syn.runs if r.name == name)
        plot_spectra(ax, res.nominal[name], res.after.get(name), f"{run.voltage:g} V (held out)")
        rot = float(np.mean(res.nominal[name].measured_speed)) / (2 * math.pi)
        ax.axvline(rot, color="gray", lw=0.6, ls=":")
        ax.text(rot, ax.get_ylim()[1], " rotation rate", fontsize=7, va="top", color="gray")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_file(out / "spectra_0.2_0.5V.png", "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)
    truth = syn.answer["model_effects"]
    found = res.decision.winner.parameters if res.decision.winner else {}
    summary = {
        "verdict": res.effect,
        "confidence": res.decision.confidence,
        "truth": truth,
        "found": found,
        "gap_before": res.gap_before,
        "gap_after": res.gap_after,
        "heldout_runs": held,
    }
    lines = [
        "# The paper's case: position-dependent friction at the lower disk",
        "",
        "Regenerate with `drill-env discrepancy-study --paper-case-only --out results/discrepancy`.",
        "",
        "Sec. 4.1 of Mihajlovic et al. (2004): at 0.2 V and 0.5 V the measured lower-disk speed oscillates "
        "once per revolution of the lower disk, which the model (static friction depending on speed only) "
        "cannot produce. Data made to look like those runs: brake preset, 1 kHz, 2000 counts/rev, constant "
        "0.2, 0.5, 0.7 and 1.0 V for 300 s each plus three quasi-random identification runs, with a "
        f"position-dependent lower friction of magnitude a1 = {magnitude:g}. The 0.2 V and 0.5 V runs are held "
        "out: the effect is fitted on the others and judged on them.",
        "",
        f"**{res.verdict_line()}**",
        "",
        "| parameter | truth (answer file) | found |",
        "|---|---|---|",
    ]
    for k, v in truth.items():
        lines.append(f"| {k} | {v:.4g} | {found.get(k, float('nan')):.4g} |")
    lines += ["", "| metric (held-out 0.2 V, 0.5 V) | nominal | with the effect |", "|---|---|---|"]
    for k, v in res.gap_before.items():
        lines.append(f"| {k} | {v:.4g} | {res.gap_after.get(k, float('nan')):.4g} |")
    lines += [
        "",
        "![spectra](spectra_0.2_0.5V.png)",
        "",
        "Power spectra of the lower-disk speed at 0.2 V and 0.5 V (dotted: the mean rotation rate of the "
        "lower disk): the measurement has lines at the rotation rate and its harmonics that the nominal "
        "model lacks; the model with the identified effect reproduces them. Full report: "
        "[analysis/report.md](analysis/report.md).",
        "",
    ]
    atomic_write_text(out / "paper_case.md", "\n".join(lines))
    atomic_write_text(out / "paper_case.json", json.dumps(summary, indent=2, default=float) + "\n")
    return summary
