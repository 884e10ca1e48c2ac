"""``report.md`` and figures of a discrepancy analysis."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np

from drill_env.outputs import save_figure

__all__ = ["write_report", "plot_spectra", "parameter_table"]


def _fmt(x, digits=4) -> str:
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, (float, np.floating)):
        if not math.isfinite(float(x)):
            return "-"
        return f"{float(x):.{digits}g}"
    return str(x)


def _table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(v) for v in r) + " |")
    return "\n".join(lines)


def plot_spectra(ax, comp_nominal, comp_after=None, title=""):
    band = (comp_nominal.freqs > 0) & (comp_nominal.freqs <= 2.0)
    f = comp_nominal.freqs[band]
    ax.loglog(f, comp_nominal.psd_measured[band], color="k", lw=1.2, label="measured")
    ax.loglog(f, comp_nominal.psd_model[band], color="tab:red", lw=1, label="nominal model")
    if comp_after is not None:
        ax.loglog(f, comp_after.psd_model[band], color="tab:blue", lw=1, ls="--", label="with effect")
    ax.set_xlabel("frequency [Hz]", fontsize=FONT)
    ax.set_ylabel("PSD of lower speed\n[(rad/s)^2/Hz]", fontsize=FONT)
    ax.set_title(title, fontsize=FONT)
    ax.tick_params(labelsize=FONT)


# The report's figures: at most FIGURE_WIDTH wide, no text below FONT (legible where the docs
# draw a figure, 724 px wide: drill_env._figures' size rule)
FIGURE_WIDTH = 8.0  # [in]
FONT = 9.0  # [pt]


def _run_grid(k: int, row_height: float = 2.9):
    """A figure of ``k`` panels, two to a row, FIGURE_WIDTH wide; returns (figure, axes in
    order); the panels a last odd row leaves over are hidden."""
    from drill_env._figures import subplots

    ncol = min(2, k)
    nrow = -(-k // ncol)
    fig, axes = subplots(nrow, ncol, figsize=(FIGURE_WIDTH, row_height * nrow + 0.7), squeeze=False)
    flat = list(axes.flat)
    for ax in flat[k:]:
        ax.set_visible(False)
    return fig, flat[:k]


def _legend_below(fig, ax) -> None:  # noqa: ANN001
    """One legend for the figure (the entries of ``ax``), centred below the panels."""
    from drill_env._figures import renderer

    handles, labels = ax.get_legend_handles_labels()
    leg = fig.legend(handles, labels, loc="lower center", ncol=len(handles), fontsize=FONT, frameon=False)
    height = leg.get_window_extent(renderer(fig)).height / (fig.dpi * fig.get_figheight())
    fig.tight_layout(rect=(0, height + 0.01, 1, 1))


def _decade_ticks(axis, limits: tuple[float, float]) -> None:  # noqa: ANN001
    """Ticks of a symmetric-log axis (linear within +-1) at 0 and at whole decades from 10 on
    (10^0 would sit on 0's label), every k-th decade of each side so that at most seven are
    labelled: labels clear of each other at the size the figure is drawn."""
    lo, hi = limits
    top = max(abs(lo), abs(hi), 10.0)
    decades = list(range(1, int(np.floor(np.log10(top))) + 1))
    pos = [k for k in decades if 10.0**k <= hi]
    neg = [k for k in decades if -(10.0**k) >= lo]
    step = max(1, -(-(len(pos) + len(neg)) // 6))
    pos, neg = pos[::-1][::step], neg[::-1][::step]  # the largest decade of each side kept
    ticks = [0.0] + [10.0**k for k in pos] + [-(10.0**k) for k in neg]
    axis.set_ticks(sorted(ticks))
    axis.set_ticklabels(
        [
            ("0" if t == 0 else f"${'-' if t < 0 else ''}10^{{{int(round(np.log10(abs(t))))}}}$")
            for t in sorted(ticks)
        ]
    )


def _figures(res, out: Path) -> list[tuple[str, str]]:
    from matplotlib.lines import Line2D

    from drill_env._figures import subplots

    figs = []
    d = res.decision
    held = [n for n in d.heldout_runs if n in res.nominal]
    runs = {r.name: r for r in res.dataset.runs}

    # candidate gains
    from matplotlib.patches import Patch

    # 7 in wide, 9 pt text: legible where the docs draw a figure (724 px; drill_env._figures)
    fig, ax = subplots(figsize=(7, 0.32 * len(d.scores) + 1.6))
    names = [s.name for s in d.scores]
    # A candidate can make the held-out fit worse (gain <= 0): a symmetric-log axis draws
    # those as bars to the left of zero instead of stubs at an arbitrary floor.
    gains = [s.gain for s in d.scores]
    colors = ["tab:green" if s.significant else "tab:gray" for s in d.scores]
    ax.barh(names, gains, color=colors)
    ax.scatter([s.threshold for s in d.scores], names, marker="|", s=200, color="k", zorder=3)
    ax.axvline(0.0, color="k", lw=0.6)
    ax.set_xscale("symlog", linthresh=1.0)
    _decade_ticks(ax.xaxis, ax.get_xlim())
    ax.set_xlabel("held-out gain: drop of the sum of squares\n[noise units] (< 0: worse)", fontsize=9)
    ax.set_title("Candidate effects on the held-out runs", fontsize=10)
    ax.tick_params(labelsize=9)
    ax.legend(
        handles=[
            Patch(color="tab:green", label="significant"),
            Patch(color="tab:gray", label="not significant"),
            Line2D([], [], color="k", marker="|", ls="", ms=12, label="significance threshold"),
        ],
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, out / "candidates.png", dpi=150)
    figs.append(("candidates.png", "Held-out gain of each candidate against its significance threshold."))

    # equation error per run
    eqs = res.equations
    fig, axes = subplots(2, 1, figsize=(8, 5.6), sharex=True)
    for disk, ax in zip(("upper", "lower"), axes, strict=False):
        for i, eq in enumerate(eqs):
            w = getattr(eq, disk)
            if len(w) == 0:
                continue
            x = i + w.t / max(eq.run.duration, 1e-9) * 0.9
            ax.plot(x, w.z, ".", ms=2)
        ax.axhline(3, color="k", lw=0.5, ls=":", label="+-3 noise floors")
        ax.axhline(-3, color="k", lw=0.5, ls=":")
        ax.set_ylabel(f"{disk} disk: residual torque\n/ its noise floor [-]", fontsize=9)
        ax.set_yscale("symlog", linthresh=3)
        # decades only: +-3 (the dotted lines) and 30 sit too close to their neighbours on
        # this axis for their labels to stay apart at the size the figure is drawn
        lim = max(10.0, float(np.max(np.abs(ax.get_ylim()))))
        ticks = [t for t in (1000, 100, 10) if t <= lim]
        ax.set_yticks([-t for t in ticks] + [0] + ticks[::-1])
        ax.set_yticklabels([f"{-t:g}" for t in ticks] + ["0"] + [f"{t:g}" for t in ticks[::-1]], fontsize=9)
    axes[0].legend(loc="upper right", fontsize=9)
    axes[0].set_title("Nominal equation error per window (each run's windows in time order)", fontsize=10)
    axes[1].set_xticks(np.arange(len(eqs)) + 0.45)
    # the run's name, then what it is on short lines ("(varying\n-5-5 V)"): labels clear of
    # their neighbours at 9 pt with ten runs
    width = max(6, int(80 / max(len(eqs), 1)))
    axes[1].set_xticklabels(
        [
            eq.run.label.split(" (")[0]
            + "".join(
                "\n" + w
                for w in textwrap.wrap(eq.run.label[len(eq.run.label.split(" (")[0]) :].strip(), width)
            )
            for eq in eqs
        ],
        fontsize=9,
    )
    axes[1].set_xlabel("run (windows from the start to the end of each recording)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, out / "equation_error.png", dpi=150)
    figs.append(
        (
            "equation_error.png",
            "Nominal equation error per window, in units of its noise floor "
            "(dotted: +-3); each run's windows in time order.",
        )
    )

    if held:
        # spectra of the held-out runs
        k = len(held)
        fig, axes = _run_grid(k)
        for ax, name in zip(axes, held, strict=False):
            plot_spectra(ax, res.nominal[name], res.after.get(name), runs[name].label)
        _legend_below(fig, axes[0])
        save_figure(fig, out / "spectra.png", dpi=110)
        figs.append(
            (
                "spectra.png",
                "Power spectra of the lower-disk speed on the held-out runs: measured, "
                "free-running nominal model and model with the effect.",
            )
        )
        # residual spectra of the short-horizon prediction
        fig, axes = _run_grid(k)
        for ax, name in zip(axes, held, strict=False):
            c = res.nominal[name]
            band = (c.freqs > 0) & (c.freqs <= 10.0)
            ax.loglog(c.freqs[band], c.psd_short_residual[band], color="tab:red", lw=1, label="nominal")
            if name in res.after:
                a = res.after[name]
                ax.loglog(
                    a.freqs[band], a.psd_short_residual[band], color="tab:blue", lw=1, label="with effect"
                )
            ax.set_title(runs[name].label, fontsize=FONT)
            ax.set_xlabel("frequency [Hz]", fontsize=FONT)
            ax.set_ylabel("PSD of the speed residual\n[(rad/s)^2/Hz]", fontsize=FONT)
            ax.tick_params(labelsize=FONT)
        fig.suptitle("lower-disk speed residual: 2 s prediction - measured", fontsize=FONT + 1)
        _legend_below(fig, axes[0])
        save_figure(fig, out / "residual_spectra.png", dpi=110)
        figs.append(
            (
                "residual_spectra.png",
                "Spectra of the short-horizon speed residual (measured minus "
                "model restarted from the measured state every few seconds), held-out runs.",
            )
        )
        # trajectories
        fig, axes = subplots(k, 1, figsize=(FIGURE_WIDTH, 2.2 * k + 0.6), squeeze=False, sharex=True)
        for ax, name in zip(axes[:, 0], held, strict=False):
            c = res.nominal[name]
            sel = c.t <= min(c.t[-1], 40.0)
            ax.plot(c.t[sel], c.measured_speed[sel], color="k", lw=0.8, label="measured")
            ax.plot(c.t[sel], c.short_speed[sel], color="tab:red", lw=0.8, label="nominal, short horizons")
            if name in res.after:
                ax.plot(
                    c.t[sel],
                    res.after[name].short_speed[sel],
                    color="tab:blue",
                    lw=0.8,
                    ls="--",
                    label="with effect, short horizons",
                )
            ax.set_ylabel("lower speed [rad/s]", fontsize=FONT)
            ax.set_title(runs[name].label, fontsize=FONT)
            ax.tick_params(labelsize=FONT)
        axes[-1, 0].set_xlabel("time since start of recording [s]", fontsize=FONT)
        _legend_below(fig, axes[0, 0])
        save_figure(fig, out / "trajectories.png", dpi=110)
        figs.append(
            (
                "trajectories.png",
                "Lower-disk speed, first 40 s of each held-out run: measured and "
                "models restarted from the measured state.",
            )
        )

    # bifurcation points
    const = [n for n, c in res.nominal.items() if c.features_measured is not None]
    if const:
        fig, ax = subplots(figsize=(6.5, 4.2))
        for n in const:
            c = res.nominal[n]
            v = c.voltage
            fm, fs = c.features_measured, c.features_model
            mk = "o" if n in d.heldout_runs else "s"
            ax.plot([v] * 3, [fm.min_speed, fm.mean_speed, fm.max_speed], mk, color="k", mfc="none")
            ax.plot([v - 0.04] * 3, [fs.min_speed, fs.mean_speed, fs.max_speed], "x", color="tab:red")
            if n in res.after:
                fa = res.after[n].features_model
                ax.plot([v + 0.04] * 3, [fa.min_speed, fa.mean_speed, fa.max_speed], "+", color="tab:blue")
        ax.plot([], [], "o", color="k", mfc="none", label="measured (circle: held out)")
        ax.plot([], [], "x", color="tab:red", label="nominal model")
        if res.after:
            ax.plot([], [], "+", color="tab:blue", label="with effect (held-out runs)")
        ax.set_xlabel("constant voltage u [V]", fontsize=FONT)
        ax.set_ylabel("lower speed min / mean / max [rad/s]", fontsize=FONT)
        ax.tick_params(labelsize=FONT)
        ax.legend(fontsize=FONT)
        fig.tight_layout()
        save_figure(fig, out / "bifurcation.png", dpi=110)
        figs.append(
            (
                "bifurcation.png",
                "Experimental bifurcation-diagram points (min, mean, max of the "
                "lower-disk speed over the second half of each constant-voltage run).",
            )
        )
    return figs


def written_value(res, name: str) -> float:
    """The value of parameter ``name`` in the model the analysis chose (``model.yaml``, or
    ``model_rejected.yaml`` when that model was not written as the result; the nominal when the
    chosen model is the nominal one)."""
    model = res.corrected if res.corrected is not None else res.params
    return float(getattr(model, name))


def parameter_table(res) -> list[str]:
    """Markdown lines: nominal against recalibrated parameters with their 95 % intervals.

    The "fitted" column is the value of the chosen model (what ``model.yaml`` holds), always."""
    d = res.decision
    if not d.parameters:
        if d.calibration is not None:
            return [
                "The identified parameters were refitted on the training runs; none moved beyond its "
                "test, so every parameter keeps its nominal value in the chosen model.",
                "",
            ]
        return ["The parameters were taken as exact (no recalibration).", ""]
    rows = []
    for f in d.parameters:
        value = written_value(res, f.name)
        if f.moved:
            lo, hi = f.ci95
            interval = f"[{lo:.4g}, {hi:.4g}]"
            change = f"{value / f.nominal - 1.0:+.2%}" if f.nominal else "-"
            if f.excludes_nominal:
                status = "moved: recalibrated"
            else:
                status = "refitted jointly, interval holds the nominal: not a resolved change"
            if not f.identified:
                status += " (fixed by the data only jointly with others)"
            if f.out_of_prior:
                status += f"; OUT OF PRIOR (beyond +-{f.prior_sd / abs(f.nominal):.0%}), see below"
        elif f.identified:
            interval, change, status = "-", "-", "excited, no significant change: kept nominal"
        else:
            interval, change, status = "-", "-", "not excited by the data: kept nominal"
        rows.append([f.name, f.nominal, value, interval, change, status])
    k_theta = res.params.string_stiffness
    lines = [
        "Every identified parameter is refitted on the training runs jointly with the named effect "
        "(if any), in the same equation-error windows and noise units as the effects. The data fix "
        f"ratios, not the scale: the string stiffness is kept at its nominal {k_theta:g} N m/rad and "
        "sets it. Each parameter carries a weak prior at its nominal value (standard deviation 25 % "
        "of it); a parameter the data do not pin down three times better than that is not excited and "
        "stays nominal. The parameters that moved are chosen by forward selection on the training runs "
        "(each one must lower the sum of squares by more than max(chi2_1 quantile at 1e-3, ln n)), "
        "jointly with the named effect, and refitted with the others at nominal; only those enter "
        "`model.yaml`. Intervals: posterior 95 % in the logarithm of the parameter's magnitude (each "
        "keeps the sign physics gives the parameter), at least as wide as the jackknife over training runs. A "
        "parameter is *moved* when its interval excludes the nominal value; one refitted jointly whose "
        "interval holds the nominal value is not a resolved change. The fitted column is the value in "
        "the chosen model.",
        "",
        _table(["parameter", "nominal", "fitted", "95 % interval", "change", "status"], rows),
        "",
    ]
    lines += out_of_prior_lines(d.parameters)
    st = d.structure
    if "recalibration_gain" in st and d.recalibrated:
        lines += [
            f"The recalibrated model lowers the held-out sum of squares by {st['recalibration_gain']:.4g} "
            f"against a threshold of {st['recalibration_threshold']:.4g} "
            f"({'confirmed' if st['recalibration_confirmed'] else 'not confirmed'} on the held-out runs).",
            "",
        ]
    return lines


def out_of_prior_lines(fits) -> list[str]:
    """A paragraph per recalibration beyond its prior, with what else gives the same data."""
    from drill_env.discrepancy.calibrate import ALTERNATIVE_EXPLANATIONS

    far = [f for f in fits if f.out_of_prior]
    if not far:
        return []
    lines = [
        "### Recalibrations outside the prior",
        "",
        "The paper's values are thought to be known to within the prior's width; a recalibration "
        "beyond it is more likely something else that produces the same equation error. Check "
        "these before trusting the new value:",
        "",
    ]
    for f in far:
        lines.append(
            f"- **{f.name}** {f.value / f.nominal - 1.0:+.1%} "
            f"({abs(f.value - f.nominal) / f.prior_sd:.1f} prior widths): the same data come from "
            f"{ALTERNATIVE_EXPLANATIONS.get(f.name, 'another torque of the same shape')}."
        )
    return lines + [""]


def _sensor_lines(res) -> list[str]:
    chk = res.sensor_check
    if not chk:
        return []
    rows = [
        [k, chk["recalibrated_model"][k], chk["with_effect"].get(k, float("nan")), k in chk["worse"]]
        for k in chk["recalibrated_model"]
    ]
    verdict = (
        f"{chk['effect']} makes {', '.join(chk['worse'])} worse beyond their noise, so it is not named "
        "even though it improves the held-out equation error."
        if chk["worse"]
        else f"{chk['effect']} makes no sensor-space gap worse beyond its noise."
    )
    return [
        "## Everywhere better?",
        "",
        "A named effect must improve the model everywhere it is measured: besides the held-out "
        "equation error, the short-horizon trajectories and the steady-state features of the held-out "
        "runs, each against the recalibrated model without the effect. A gap counts as worse when it "
        "grows by more than 25 % plus its noise floor (angle noise, smooth-speed noise, 0.05 of stuck "
        "time, 0.25 s of period).",
        "",
        _table(["held-out gap", "recalibrated model", "with the effect", "worse"], rows),
        "",
        verdict,
        "",
    ]


def _rotation_section(res) -> list[str]:
    """A named effect locked to a disk's rotation: the physical and the sensor explanation side
    by side, with their held-out scores, and what each means on the rig."""
    from drill_env.recordings.effects import CANDIDATES

    kinds = {c.name: c.kind for c in CANDIDATES}
    d = res.decision
    disks = []
    for e in res.effects:
        for disk in ("lower", "upper"):
            if e in (f"position_friction_{disk}", f"encoder_eccentricity_{disk}") and disk not in disks:
                disks.append(disk)
    if not disks:
        return []
    lines = ["## Sensor or friction?", ""]
    for disk in disks:
        names = (f"encoder_eccentricity_{disk}", f"position_friction_{disk}")
        scores = {s.name: s for s in d.scores if s.name in names}
        rows = [
            [
                n,
                "sensor" if kinds[n] == "measurement" else "physical",
                "no torque: the angle is read wrong, a sin(theta + phi) once per revolution"
                if kinds[n] == "measurement"
                else "a friction that changes with the disk's angle",
                scores[n].gain,
                scores[n].threshold,
                scores[n].significant,
                ", ".join(f"{k}={v:.4g}" for k, v in scores[n].parameters.items()),
                "named" if n in res.effects else "",
            ]
            for n in names
            if n in scores
        ]
        named = next(n for n in names if n in res.effects)
        if kinds[named] == "measurement":
            m = res.measurement
            a = getattr(m, f"{disk}_encoder_eccentricity") if m is not None else float("nan")
            phi = getattr(m, f"{disk}_encoder_phase") if m is not None else float("nan")
            what = (
                f"**A sensor effect.** The {disk} encoder reads its disk's angle wrong once per revolution: "
                f"reading = theta + a sin(theta + phi) with a = {a:.4g} rad ({a * 180 / 3.141592653589793:.3g} "
                f"deg) and phi = {phi:.4g} rad. It exerts no torque: the rig moves as the plant says, "
                "and the corrected model's plant has no effect for it; `model.yaml` holds it in its "
                "`measurement:` section, and the simulated readings of the held-out runs (the checks below) "
                f"went through it. On the rig: look at the {disk} encoder's mounting (an eccentric or tilted "
                "code disk, a loose or bent coupling), not at the brake; once it is centred, record again."
            )
        else:
            what = (
                f"**A physical effect.** A friction of the {disk} disk that changes with its angle: look at "
                f"the {disk} disk and its contact (brake pads, runout of the disk)."
            )
        lines += [
            what,
            "",
            f"A line locked to the {disk} disk's rotation has a physical and a sensor explanation; both "
            "are candidates of the library, scored on the same held-out runs (held-out gain against its "
            "threshold), and the larger margin is named:",
            "",
            _table(
                [
                    "candidate",
                    "kind",
                    "what it is",
                    "held-out gain",
                    "threshold",
                    "significant",
                    "fitted",
                    "",
                ],
                rows,
            ),
            "",
        ]
    return lines


def _signature_section(res) -> list[str]:
    """What to look for on the rig when no library effect explains the residual."""
    sig = getattr(res, "signature", None)
    if sig is None:
        return []
    rows = [
        [
            r["run"],
            "varying" if r["voltage_v"] is None else f"{r['voltage_v']:g}",
            f"{r['lower_rotation_hz']:.4g}",
            f"{r['upper_rotation_hz']:.4g}",
            f"{r['amplitude_nm'].get('lower', float('nan')):.3g}",
            f"{r['amplitude_nm'].get('upper', float('nan')):.3g}",
            f"{r.get('excess_ss', float('nan')):.4g}",
            "yes" if r["shown"] else "no",
        ]
        for r in sig.runs
    ]
    drops = ", ".join(f"{k} {v:.4g}" for k, v in sorted(sig.drops.items(), key=lambda kv: -kv[1]))
    explain: list[str] = []
    if sig.explanations:
        explain = [
            "A line locked to a disk's rotation has two kinds of explanation, scored on the same "
            "residual with coefficients common to the runs (drop of the sum of squares in noise units, "
            "and the BIC score: the drop minus k ln n for k fitted parameters; the larger score fits "
            "better). Check both on the rig: the physical one at the disk and its brake, the sensor one "
            "at the encoder's mounting.",
            "",
            _table(
                ["explanation", "kind", "what it is", "drop", "k", "score", "fitted"],
                [
                    [
                        e["explanation"],
                        e["kind"],
                        e["what"],
                        e["drop"],
                        e["k"],
                        e["score"],
                        ", ".join(f"{k}={v:.4g}" for k, v in e["parameters"].items()),
                    ]
                    for e in sig.explanations
                ],
            ),
            "",
        ]
    return [
        "## What to look for",
        "",
        f"The residual the library does not explain is {sig.summary()}.",
        "",
        "Each hypothesis is a sinusoidal torque on both disks with its own amplitude and phase per run, "
        "fitted through the window kernel of the equation error: a fixed frequency in time (the common "
        "line, refined), harmonics 1-3 of either disk's angle (a line that moves with that disk's speed "
        "from run to run), or the measured voltage's deviation from its run mean. The largest drop of "
        f"the sum of squares (noise units) names the clock the line keeps: {drops}. A run shows the line "
        "when the drop on one of its disks passes the chi-square test at 1 %; its residual excess is the "
        "sum of squares (noise units, both disks, after recalibration) minus the number of windows: the "
        "residual concentrates where it is largest.",
        "",
        _table(
            [
                "run",
                "u [V]",
                "lower rotation [Hz]",
                "upper rotation [Hz]",
                "lower torque [N m]",
                "upper torque [N m]",
                "residual excess",
                "shows",
            ],
            rows,
        ),
        "",
        *explain,
    ]


def _timing_section(res) -> list[str]:
    """Whether the voltage column keeps the angles' clock (see drill_env.discrepancy.timing)."""
    lag = getattr(res, "voltage_lag", None)
    applied = int(res.dataset.meta.get("voltage_lag_samples", 0))
    if lag is None:
        return []
    out = ["## Timing of the voltage column", ""]
    if applied:
        out += [
            f"The voltage column was shifted by {applied:+d} samples before the analysis "
            f"(--voltage-lag {applied}): the motor is taken to have seen u[i {'+' if applied > 0 else '-'} "
            f"{abs(applied)}] at sample i; each run lost {abs(applied)} samples at one end.",
            "",
        ]
    if not lag.runs:
        return [*out, "No run has voltage steps: the timing of the voltage column cannot be checked.", ""]
    rows = [
        [f"{k:+d}", f"{k * lag.dt * 1e3:+.3g}", f"{lag.drops_train[k]:.4g}", f"{lag.drops_heldout[k]:.4g}"]
        for k in sorted(lag.drops_train)
    ]
    out += [
        ("**" + lag.describe() + ".**")
        if lag.found
        else (lag.describe()[0].upper() + lag.describe()[1:] + "."),
        "",
        "At every voltage step a voltage column recorded on another clock moves the motor torque to the "
        "wrong sample, and the upper disk's equation error shows a pulse there. Each row re-times the "
        "motor torque by whole samples (positive: the column lags the angles, the motor saw the voltage "
        "of a later row) and gives the drop of the sum of squares (noise units) on the runs with voltage "
        f"steps ({', '.join(lag.runs)}); nothing is fitted. A lag is claimed when it passes "
        f"{lag.threshold:.3g} (chi-square, 1 degree of freedom, 1e-3 over the lags) over all runs, is the "
        "best lag on the training runs and improves them, is not contradicted by the held-out runs (no "
        "other lag better there by the level, no worse by it) and beats every other lag by the level. The data are not shifted: rerun with "
        "`--voltage-lag K` to analyse them re-timed.",
        "",
        _table(["voltage lag [samples]", "[ms]", "drop, training", "drop, held-out"], rows),
        "",
    ]
    return out


def write_report(res, out: Path, *, figures: bool = True) -> Path:
    d = res.decision
    lines = ["# Model-discrepancy report", ""]
    lines += [f"**{res.verdict_line()}**", ""]
    for note in res.validity_warnings:
        lines += [f"> Warning: {note}.", ""]
    ds = res.dataset
    lines += [
        f"Dataset: {len(ds.runs)} runs, preset `{ds.preset}`, {ds.encoder_counts_per_rev} encoder counts "
        f"per revolution, {ds.sample_rate_hz:g} Hz. Angle noise estimated from the data: "
        f"upper {res.noise.upper:.3g} rad, lower {res.noise.lower:.3g} rad "
        f"(quantisation alone {res.noise.quantisation:.3g} rad)."
        + ("" if res.params.name == ds.preset else f" Nominal model: `{res.params.name}` (--params)."),
        "",
        f"Training runs: {', '.join(d.train_runs)}. Held-out runs: {', '.join(d.heldout_runs)}.",
        "",
        f"Reason: {d.reason}. Bootstrap over runs: {d.bootstrap_counts}.",
        "",
    ]
    lines += _timing_section(res)
    if res.corrected is not None and res.model_rejected:
        lines += [
            "**The chosen model is not written as the result.** Simulated on the held-out runs it makes "
            + ", ".join(res.model_check["worse"])
            + " worse than the nominal model beyond their noise (see *Gap before and after*): it "
            "absorbs part of something the library does not hold, and would mislead a controller "
            "design. It is kept as `model_rejected.yaml` for inspection; the nominal preset stays "
            "the model to use.",
            "",
        ]
    elif res.corrected is not None and getattr(res, "measurement", None) is not None:
        lines += [
            "The chosen model is written as `model.yaml`: the recalibrated plant (its `effects:` entry "
            "for a physical effect) and a `measurement:` section with the encoders' reading errors. It is "
            "a plant file: `drill-env synth --plant model.yaml` records data through those encoders and "
            "`drill_env.plant_file.read_plant_file` reads it; `drill_env.load_params` reads plants alone "
            "and refuses it (delete the `measurement:` section to simulate the plant alone).",
            "",
        ]
    elif res.corrected is not None:
        lines += [
            "The chosen model (recalibrated parameters, plus the effect if one is named) is written as a rig configuration, `model.yaml` (its `effects:` entry); "
            '`drill_env.simulate("model.yaml", ...)` and `drill_env.load_params("model.yaml")` accept it. '
            "Times in it count from the start of a recording (simulate with `t0 = 0` there).",
            "",
        ]
    lines += ["## Recalibrated parameters", ""]
    lines += parameter_table(res)
    lines += ["## Where the nominal model disagrees", ""]
    rows = []
    for w in res.where:
        rows.append(
            [
                w["label"],
                w["upper_ss_per_window"],
                w["lower_ss_per_window"],
                w.get("short_horizon_angle_over_floor", float("nan")),
                w.get("spectrum_distance_db", float("nan")),
                ", ".join(f"{f:.3g}" for f in w.get("disagreeing_frequencies_hz", [])) or "-",
            ]
        )
    lines += [
        "Equation error as sum of squares per window in noise units (1 = at the noise floor); short-horizon "
        "angle error over the angle noise; spectral distance of the lower-disk speed [dB] and the "
        "frequencies [Hz] where the spectra differ by more than 6 dB.",
        "",
        _table(
            [
                "run",
                "upper SS/window",
                "lower SS/window",
                "short-horizon angle / floor",
                "spectrum distance [dB]",
                "disagreeing frequencies [Hz]",
            ],
            rows,
        ),
        "",
    ]
    const = [w for w in res.where if "steady_measured" in w]
    if const:
        rows = []
        for w in const:
            m, s = w["steady_measured"], w["steady_model"]
            rows.append(
                [
                    w["label"],
                    m["mean_speed"],
                    s["mean_speed"],
                    m["min_speed"],
                    s["min_speed"],
                    m["max_speed"],
                    s["max_speed"],
                    m["period"],
                    s["period"],
                    m["stick_fraction"],
                    s["stick_fraction"],
                ]
            )
        lines += [
            "Steady state (second half of each constant-voltage run), measured vs nominal model:",
            "",
            _table(
                [
                    "run",
                    "mean meas",
                    "mean model",
                    "min meas",
                    "min model",
                    "max meas",
                    "max model",
                    "period meas [s]",
                    "period model [s]",
                    "stuck meas",
                    "stuck model",
                ],
                rows,
            ),
            "",
        ]
    ln = res.line
    lines += [
        f"Strongest common spectral line of the residual: {ln.frequency_hz:.4g} Hz, drop of the sum of squares "
        f"{ln.reduction:.4g} against a threshold of {ln.threshold:.4g} "
        f"({'significant' if ln.significant else 'not significant'}; "
        + (
            "what it is locked to: see *What to look for*)."
            if getattr(res, "signature", None) is not None
            else f"{'its frequency near the lower disk rotation rate' if ln.related_to_rotation else 'its frequency away from the lower disk rotation rate'})."
        ),
        "",
    ]
    lines += _signature_section(res)
    lines += [
        "## Which effect",
        "",
    ]
    rows = [
        [
            s.name,
            s.gain,
            s.threshold,
            s.significant,
            ", ".join(f"{k}={v:.4g}" for k, v in s.parameters.items()),
            s.note or "",
        ]
        for s in d.scores
    ]
    lines += [
        "Each candidate is fitted on the training runs jointly with the identified parameters and scored on "
        "the held-out runs as an addition to the recalibrated model: the gain is the drop of the held-out "
        "sum of squares (noise units) against recalibration alone, normalised by the remaining misfit. A "
        "candidate is significant when it passes the Benjamini-Hochberg step-up rule at false-discovery "
        "level 1e-3 over the admissible candidates and the penalty k ln n; the threshold shown is "
        "max(chi2 quantile at 1e-3/m, k ln n), the strictest step.",
        "",
        _table(["candidate", "held-out gain", "threshold", "significant", "fitted parameters", "note"], rows),
        "",
    ]
    if res.second:
        lines += [
            "Second effect (greedy forward step, same held-out rule, with the first effect and the "
            f"identified parameters refitted jointly): {res.second.get('reason', 'not tried')}.",
            "",
        ]
    lines += _rotation_section(res)
    lines += _sensor_lines(res)
    lines += [
        "## Gap before and after, held-out runs",
        "",
    ]
    keys = list(res.gap_before)
    worse = set(res.model_check.get("worse", []))
    rows = [[k, res.gap_before[k], res.gap_after.get(k, float("nan")), k in worse] for k in keys]
    lines += [_table(["metric", "nominal model", "chosen model", "worse than nominal"], rows), ""]
    if res.model_check:
        lines += [
            "Before `model.yaml` is written, the chosen model's sensor-space gaps on the held-out runs are "
            "compared with the nominal model's; a gap counts as worse when it grows by more than 25 % plus "
            "its noise floor. "
            + (
                "It is worse in " + ", ".join(sorted(worse)) + ": not written (`model_rejected.yaml`)."
                if worse
                else "It is nowhere worse: written as `model.yaml`."
            ),
            "",
        ]
    if res.corrected is None:
        lines += [
            "Neither an effect nor new parameter values were needed: the model and its gap are unchanged.",
            "",
        ]
    else:
        lines += [
            (
                "The rejected model (`model_rejected.yaml`): "
                if res.model_rejected
                else "The chosen model (`model.yaml`): "
            )
            + (f"the effect {d.effect}" if d.named else "no effect")
            + (
                ", with the recalibrated parameters " + ", ".join(f.name for f in d.recalibrated)
                if d.recalibrated
                else ""
            )
            + ".",
            "",
        ]
    if figures:
        figs = _figures(res, out)
        lines += ["## Figures", ""]
        for fn, cap in figs:
            lines += [f"![{fn}]({fn})", "", cap, ""]
    from drill_env.outputs import atomic_write_text

    return atomic_write_text(out / "report.md", "\n".join(lines))
