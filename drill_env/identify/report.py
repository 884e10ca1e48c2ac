"""Files of ``drill-env identify``: rig.yaml, identification.json, report.md and its figures."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.identify.identification import REFUSED_METHOD, Identification
from drill_env.outputs import atomic_write_text, save_figure
from drill_env.params import IDENTIFIED_PARAMETERS, RigParams

__all__ = ["identification_json", "write_outputs", "UNITS"]

# the report's figures: at most FIGURE_WIDTH wide, no text below FONT (legible where the docs
# draw a figure, 724 px wide: drill_env._figures' size rule)
FIGURE_WIDTH = 8.0  # [in]
FONT = 9.0  # [pt]
MISFIT_WARN = 10.0  # residual variance (noise floor 1) above which the report names a misfit

UNITS = {
    "motor_constant": "N m/V",
    "upper_inertia": "kg m^2",
    "upper_static_pos": "N m",
    "upper_static_neg": "N m",
    "upper_viscous_pos": "N m s/rad",
    "upper_viscous_neg": "N m s/rad",
    "lower_inertia": "kg m^2",
    "string_stiffness": "N m/rad",
    "lower_static": "N m",
    "lower_viscous": "N m s/rad",
    "lower_hump_1": "N m",
    "lower_hump_2": "N m",
    "lower_hump_rate_1": "s/rad",
    "lower_hump_rate_2": "s/rad",
}
SYMBOLS = {
    "motor_constant": "k_m",
    "upper_inertia": "J_u",
    "upper_static_pos": "T_sup",
    "upper_static_neg": "T_sun",
    "upper_viscous_pos": "b_up",
    "upper_viscous_neg": "b_un",
    "lower_inertia": "J_l",
    "string_stiffness": "k_theta",
    "lower_static": "T_sl",
    "lower_viscous": "b_l",
    "lower_hump_1": "T_1",
    "lower_hump_2": "T_2",
    "lower_hump_rate_1": "beta_1",
    "lower_hump_rate_2": "beta_2",
}


def _finite(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def identification_json(res: Identification, search: Any = None) -> dict[str, Any]:
    """The content of identification.json (``search``: the structure search that led to ``res``,
    a :class:`drill_env.structure_search.StructureSearch`)."""
    f = res.fit
    return _finite(
        {
            "effects": {n: e.as_dict() for n, e in res.effects.items()},
            "measurement": res.measurement.to_dict() if res.measurement is not None else {},
            "structure_search": search.as_dict() if search is not None else None,
            "flat_directions": res.flat_directions,
            "structure": res.structure,
            "scale": {
                "parameter": res.scale[0],
                "value": res.scale[1],
                "source": "assumed: the paper's string stiffness"
                if res.scale_assumed
                else "given by the user",
                "sentence": res.scale_sentence(),
            },
            "rig_file_written": res.params is not None,
            "parameters": {n: res.parameters[n].as_dict() for n in IDENTIFIED_PARAMETERS},
            "not_identifiable": [
                {"parameter": p.name, "run_that_identifies_it": p.needs, "note": p.note}
                for p in res.not_identifiable
            ],
            "lower_friction": res.hump,
            "steady_states": [s.as_dict() for s in res.states],
            "stick_boundary": _stick_bracket(res),
            "oscillation_hz": res.oscillation_hz,
            "fit": {
                "windows": f.n_windows,
                "weighted_sum_of_squares": f.ss,
                "residual_variance": f.residual_variance,
                "negative_side_identified": f.negative_side,
                "train_runs": res.train_runs,
                "heldout_runs": res.heldout_runs,
            },
            "heldout": {name: c.summary() for name, c in res.heldout.items()},
            "timings_s": res.timings,
        }
    )


def _stick_bracket(res: Identification) -> dict[str, Any]:
    """The highest stuck and the lowest moving positive constant voltage, and whether the
    identified stick boundary lies between them."""
    pos = [s for s in res.states if s.voltage > 0]
    stuck = [s.voltage for s in pos if s.kind == "stuck"]
    moving = [s.voltage for s in pos if s.kind != "stuck"]
    out: dict[str, Any] = {
        "highest_stuck_v": max(stuck) if stuck else None,
        "lowest_moving_v": min(moving) if moving else None,
    }
    p = res.params or res.train_params
    if p is not None:
        out["identified_uc1_v"] = p.uc1
        if stuck and moving:
            out["consistent"] = bool(max(stuck) <= p.uc1 * 1.02 and min(moving) >= p.uc1 * 0.98)
    out["bracketed"] = bool(stuck and moving)
    return out


def _fmt(x: float, digits: int = 4) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:.{digits}g}"


def _parameter_rows(res: Identification) -> list[str]:
    lines = ["| parameter | symbol | value | 95 % interval | unit | how |", "|---|---|---|---|---|---|"]
    for n in IDENTIFIED_PARAMETERS:
        p = res.parameters[n]
        ci = "-" if not all(math.isfinite(c) for c in p.ci95) else f"[{_fmt(p.ci95[0])}, {_fmt(p.ci95[1])}]"
        how = (
            p.method + (f"; {p.note}" if p.note else "") + (f"; identified by: {p.needs}" if p.needs else "")
        )
        if not p.identified and p.name != res.scale[0]:
            # never a plain number: the value the model uses is in the how column
            value, ci = "not determined", "-"
            how = f"{how}; the model uses {_fmt(p.value, 5)}"
        else:
            value = _fmt(p.value, 5)
        lines.append(f"| {n} | {SYMBOLS[n]} | {value} | {ci} | {UNITS[n]} | {how} |")
    return lines


def _effect_rows(res: Identification) -> list[str]:
    lines = [
        "| effect | parameter | value | 95 % interval | section of rig.yaml |",
        "|---|---|---|---|---|",
    ]
    for e in res.effects.values():
        section = "measurement" if e.kind == "measurement" else "effects"
        for k, v in e.parameters.items():
            lo, hi = e.ci95.get(k, (math.nan, math.nan))
            ci = f"[{_fmt(lo)}, {_fmt(hi)}]" if math.isfinite(lo) and math.isfinite(hi) else "-"
            where = section if k in e.model_fields else "(not in the file: how the fit spreads it)"
            lines.append(f"| {e.name} | {k} | {_fmt(v, 5)} | {ci} | {where} |")
    return lines


def _rounds_section(search: Any) -> list[str]:
    if not search.rounds:
        return [
            "## Structure: the effects the data need",
            "",
            f"**Not tested (verdict `{search.verdict}`): the discrepancy tests never ran, so a hidden effect "
            f"is not ruled out.** Why: {search.stopped}.",
            "",
        ]
    lines = [
        "## Structure: the effects the data need",
        "",
        "After each fit, the discrepancy tests ran on the held-out runs; an effect of the library they "
        "named was added and every base parameter re-identified jointly with its parameters. Gap: the "
        "held-out equation error per window of the model fitted without those runs (1 is the noise "
        "floor).",
        "",
        "| round | model tested | verdict | named | added | gap before | gap after | largest base changes |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in search.rounds:
        changes = sorted(r.base_changes.items(), key=lambda kv: -abs(kv[1]))[:4]
        ch = ", ".join(f"{SYMBOLS.get(k, k)} {v:+.1%}" for k, v in changes if abs(v) >= 5e-4) or "-"
        after = _fmt(r.gap_after, 3) if r.gap_after is not None else "-"
        lines.append(
            f"| {r.number} | {' + '.join(['base', *r.model_effects])} | {r.verdict} ({r.confidence:.2f}) | "
            f"{', '.join(r.named) or '-'} | {', '.join(r.added) or '-'} | {_fmt(r.gap_before, 3)} | {after} | {ch} |"
        )
    lines += ["", f"Stopped: {search.stopped}.", ""]
    if getattr(search, "refused", ""):
        lines += [
            "**The fit was refused, and the tests ran on its fitted model all the same** (at the slips "
            "its data cover, where the extrapolated T_sl does not enter): the verdict above stands, and "
            "T_sl and the hump terms tied to it are not determined; no rig file is written until the run "
            "that determines them is recorded.",
            "",
        ]
    if getattr(search, "halves", False):
        lines += [
            "Fewer than four runs: each run was cut into two halves (`NAMEa`, `NAMEb`) so that the tests "
            "have runs the fit has not seen; the parameters are fitted on the halves.",
            "",
        ]
    for r in search.rounds:
        lines.append(
            f"- Round {r.number}: {r.reason}" + (f" (signature: {r.signature})" if r.signature else "")
        )
        if r.refused:
            lines.append(
                f"  Named but not in the effects allowed (--effects): {', '.join(r.refused)}: not added."
            )
    lines.append("")
    if search.suspect:
        lines += [
            "**An unexplained residual remains: these parameters are suspect** (the residual moves them: "
            "their spread from run to run is well beyond what the noise gives): "
            + ", ".join(f"`{n}`" for n in search.suspect)
            + ". Do not trust them until the residual is explained (see `drill-env discrepancy`).",
            "",
        ]
    return lines


def _sample_params(res: Identification, n: int = 200, seed: int = 0) -> list[RigParams]:
    """Parameter sets drawn from the fit's normal approximation (valid ones only), for bands."""
    f = res.fit
    base = res.params
    if base is None or not f.free:
        return []
    rng = np.random.default_rng(seed)
    mean = np.array([f.values[n] for n in f.free])
    try:
        draws = rng.multivariate_normal(mean, f.cov, size=n, method="eigh")
    except (np.linalg.LinAlgError, ValueError):
        return []
    out = []
    for d in draws:
        values = {k: v for k, v in zip(f.free, d, strict=True) if k in IDENTIFIED_PARAMETERS}
        try:
            out.append(base.replace(**{k: float(v) for k, v in values.items()}))
        except ValueError:
            continue
    return out


def _friction_figure(res: Identification, p: RigParams, path: Path) -> None:
    """The identified friction curves (``p``: the identified rig, ``res.params``)."""
    from drill_env._figures import subplots
    from drill_env.friction import lower_friction_curve, upper_slip_friction

    fig, (ax_u, ax_l) = subplots(2, 1, figsize=(FIGURE_WIDTH, 7.8))
    top_l = max(res.max_lower_speed, 1.0)
    w_l = np.linspace(0.0, top_l, 300)
    w_up = max([abs(s.mean_upper_speed) for s in res.states] + [1.0])
    w_u = np.linspace(-w_up if res.fit.negative_side else 1e-6, w_up, 300)
    w_u = w_u[w_u != 0.0]
    draws = _sample_params(res)
    if draws:
        lo_l, hi_l = np.percentile([lower_friction_curve(q, w_l) for q in draws], [2.5, 97.5], axis=0)
        ax_l.fill_between(w_l, lo_l, hi_l, color="tab:blue", alpha=0.25, lw=0, label="95 % band")
        lo_u, hi_u = np.percentile([upper_slip_friction(q, w_u) for q in draws], [2.5, 97.5], axis=0)
        ax_u.fill_between(w_u, lo_u, hi_u, color="tab:blue", alpha=0.25, lw=0, label="95 % band")
    ax_l.plot(
        w_l, lower_friction_curve(p, w_l), color="tab:blue", lw=1.8, label="identified T_l(x3), eq. (14)"
    )
    ax_u.plot(
        w_u, upper_slip_friction(p, w_u), color="tab:blue", lw=1.8, label="identified T_fu(x2), eq. (12)"
    )
    eq = [s for s in res.states if s.kind == "equilibrium"]
    if eq:
        ax_l.plot(
            [abs(s.mean_speed) for s in eq],
            [p.string_stiffness * abs(s.mean_twist) for s in eq],
            "o",
            color="tab:red",
            mfc="none",
            ms=7,
            label="slip equilibria: k_theta |x1| at |x3|",
        )
    up = [s for s in res.states if s.upper_always_slips]
    if up:
        ax_u.plot(
            [s.mean_upper_speed for s in up],
            [p.motor_constant * s.voltage - p.string_stiffness * s.mean_twist for s in up],
            "o",
            color="tab:red",
            mfc="none",
            ms=7,
            label="runs: k_m u - k_theta mean(x1) at mean(x2)",
        )
    ax_l.set_xlabel("|x3| = lower-disk speed [rad/s]", fontsize=FONT)
    ax_l.set_ylabel("lower-disk friction T_l [N m]", fontsize=FONT)
    ax_l.set_title("lower disk", fontsize=FONT + 1)
    ax_u.set_xlabel("x2 = upper-disk speed [rad/s]", fontsize=FONT)
    ax_u.set_ylabel("upper-disk friction T_fu [N m]", fontsize=FONT)
    ax_u.set_title(
        "upper disk" + ("" if res.fit.negative_side else " (negative side not in the data)"),
        fontsize=FONT + 1,
    )
    for ax in (ax_u, ax_l):
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=FONT)
        ax.legend(loc="best", fontsize=FONT)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def _heldout_figure(res: Identification, path: Path, window_s: float = 60.0) -> bool:
    from drill_env._figures import subplots
    from drill_env.analysis.plots import legend_below

    comps = [c for c in res.heldout.values() if c.t is not None]
    if not comps:
        return False
    fig, axes = subplots(len(comps), 1, figsize=(FIGURE_WIDTH, 2.3 * len(comps) + 0.7), squeeze=False)
    for ax, c in zip(axes[:, 0], comps, strict=True):
        t = c.t - c.t[0]
        k = t <= window_s
        n = max(1, int(round(0.1 / float(t[1] - t[0])))) if t.size > 1 else 1
        box = np.ones(n) / n  # a 0.1 s average: the encoder's counts blur a slow speed otherwise
        meas = np.convolve(c.measured_speed, box, mode="same")
        free = np.convolve(c.free_speed, box, mode="same")
        ax.plot(t[k], meas[k], color="0.2", lw=1.0, label="measured (rig's speed chain, 0.1 s average)")
        ax.plot(t[k], free[k], color="tab:orange", lw=1.2, ls="--", label="identified model, free run (same)")
        run = res.dataset.run(c.run)
        ax.set_title(f"held-out run {run.label}", fontsize=FONT + 1)
        ax.set_ylabel("x3 [rad/s]", fontsize=FONT)
        ax.tick_params(labelsize=FONT)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time since the start of the recording [s]", fontsize=FONT)
    legend_below(fig, axes[0, 0].get_legend_handles_labels()[0])
    save_figure(fig, path, dpi=110)
    return True


def _bifurcation_figure(
    res: Identification, params: RigParams, path: Path, progress=None
) -> dict[str, Any] | None:
    """The bifurcation diagram of ``params`` (the identified rig, ``res.params``) with the data."""
    from matplotlib.lines import Line2D

    from drill_env._figures import subplots
    from drill_env.analysis import bifurcation_diagram
    from drill_env.analysis.plots import legend_below, plot_bifurcation

    pos = [s for s in res.states if s.voltage > 0]
    u_max = max([s.voltage for s in pos] + [1.0])
    u_max = min(5.0, u_max * 1.05) if u_max < 5.0 else 5.0
    left_out = list(params.effects.active)
    if left_out:  # the analysis is the base model's, as `drill-env bifurcation` draws a rig file with effects
        from drill_env.envs.equilibrium import nominal_params

        params = nominal_params(params)
    try:
        diagram = bifurcation_diagram(params, u_max=u_max, u_min=0.0)
    except Exception as exc:  # noqa: BLE001 (the report says why the figure is missing)
        return {"error": f"{type(exc).__name__}: {exc}"}
    fig, ax = subplots(figsize=(FIGURE_WIDTH, 6.6))
    ax.tick_params(labelsize=FONT)
    plot_bifurcation(diagram, ax=ax, legend=False, alpha=0.8)
    ax.set_title(
        f"bifurcation diagram of the identified model ({res.structure}"
        + (", its effects left out" if left_out else "")
        + ")\nwith the data's steady states",
        fontsize=FONT + 2,
    )
    handles = list(getattr(ax, "diagram_handles", []))
    if pos:
        u = [s.voltage for s in pos]
        ax.plot(u, [s.mean_speed for s in pos], "o", color="tab:red", ms=6, zorder=5)
        ax.plot(u, [s.max_speed for s in pos], "^", color="tab:red", mfc="none", ms=6, zorder=5)
        ax.plot(u, [s.min_speed for s in pos], "v", color="tab:red", mfc="none", ms=6, zorder=5)
        handles += [
            Line2D([], [], marker="o", color="tab:red", ls="none", label="data: mean x3 per run"),
            Line2D([], [], marker="^", mfc="none", color="tab:red", ls="none", label="data: max x3 (0.1 s)"),
            Line2D([], [], marker="v", mfc="none", color="tab:red", ls="none", label="data: min x3 (0.1 s)"),
        ]
    legend_below(fig, handles)
    save_figure(fig, path, dpi=110)
    return {
        "u_max": u_max,
        "effects_left_out": left_out,
        "points": {k: v.u for k, v in diagram.points.items()},
        "seconds": diagram.timings.get("total"),
    }


def write_outputs(
    res: Identification, out: Path, *, figures: bool = True, bifurcation: bool = True, search: Any = None
) -> dict[str, Any]:
    """Write rig.yaml (when every parameter the model needs is identified), identification.json,
    report.md and the figures into ``out``; returns what was written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Any] = {}
    if res.params is not None:
        header = (
            f"# {res.params.description}\n"
            "# written by `drill-env identify`; intervals and methods in identification.json\n"
        )
        if res.scale_assumed:
            header += f"# SCALE ASSUMED: {res.scale[0]} = {res.scale[1]:g} (the paper's); see report.md\n"
        import yaml

        data = res.params.to_dict()
        if res.measurement is not None and res.measurement.active:
            data["measurement"] = res.measurement.to_dict()
        atomic_write_text(out / "rig.yaml", header + yaml.safe_dump(data, sort_keys=False))
        written["rig.yaml"] = True
    record = identification_json(res, search)
    figs: dict[str, str] = {}
    bif: dict[str, Any] | None = None
    if figures and res.params is not None:
        _friction_figure(res, res.params, out / "friction.png")
        figs["friction"] = "friction.png"
        if _heldout_figure(res, out / "heldout.png"):
            figs["heldout"] = "heldout.png"
        if bifurcation:
            bif = _bifurcation_figure(res, res.params, out / "bifurcation.png")
            if bif is not None and "error" not in bif:
                figs["bifurcation"] = "bifurcation.png"
            record["bifurcation"] = bif
    atomic_write_text(
        out / "identification.json", json.dumps(_finite(record), indent=2, allow_nan=False) + "\n"
    )
    atomic_write_text(out / "report.md", _report(res, figs, bif, search))
    written.update({"identification.json": True, "report.md": True, "figures": figs})
    return written


def _report(res: Identification, figs: dict[str, str], bif: dict[str, Any] | None, search: Any = None) -> str:
    ds = res.dataset
    lines = [f"# Identification of the {res.structure} rig", ""]
    lines += [f"**{res.scale_sentence()}**", ""]
    if res.params is None:
        names = ", ".join(p.name for p in res.blocking) or "a parameter"
        lines += [
            f"**No rig file written: {names} cannot be identified from these data.** "
            "Record the runs named in the table (the plan: `drill-env identify --plan`).",
            "",
        ]
    beside = [p for p in res.not_identifiable if p.method == REFUSED_METHOD]
    if beside:
        lines += [
            "Fitted beside the refused parameters, so not identified either (their values are in the "
            f"table, for a look): {', '.join(f'`{p.name}`' for p in beside)}.",
            "",
        ]
    weak = [p for p in res.not_identifiable if p not in res.blocking and p.method != REFUSED_METHOD]
    if weak:
        lines += ["Not identifiable from these data (named, never defaulted silently):", ""]
        for p in weak:
            lines.append(
                f"- `{p.name}`: {p.note or 'interval wider than the value'}; identified by: {p.needs}"
            )
        lines.append("")
    if res.flat_directions:
        lines += ["Flat directions of the fit (the data fix only a combination of these):", ""]
        for fd in res.flat_directions:
            lines.append(
                f"- {' + '.join(f'{c:+.2f} {SYMBOLS.get(n, n)}' for n, c in fd['loadings'].items())} "
                f"(relative units): a 95 % half-width of {fd['half_width']:.3g}; "
                f"determined by: {fd['run_that_identifies_it']}"
            )
        lines.append("")
    if search is not None:
        lines += _rounds_section(search)
    elif not res.effects:
        lines += [
            "Base model only (`--no-effects`): no discrepancy tests ran; run `drill-env discrepancy "
            "DATASET --params rig.yaml` to test it.",
            "",
        ]
    if res.effects:
        lines += [
            "## Effects of the model",
            "",
            "Fitted jointly with every base parameter (their intervals from the same fit; a lag's time "
            "constant from the profile of the fit):",
            "",
            *_effect_rows(res),
            "",
        ]
    if res.fit.residual_variance > MISFIT_WARN:
        lines += [
            f"**The fit leaves {res.fit.residual_variance:.3g} times the noise floor** (1 for a model that "
            "explains the data): the rig does something the model lacks (an effect such as position-"
            "dependent friction, or another structure). The intervals are widened by it. Run `drill-env "
            "discrepancy DATASET --params rig.yaml` to name it.",
            "",
        ]
    lines += [
        f"Dataset `{ds.path.name if ds.path else 'in memory'}`: {len(ds.runs)} runs, "
        f"{ds.encoder_counts_per_rev} encoder counts per revolution, {ds.sample_rate_hz:g} Hz. "
        f"Fitted on {len(res.train_runs)} runs for validation and on all runs for the values below; "
        f"held out for validation: {', '.join(res.heldout_runs) or 'none'}.",
        "",
        "## Parameters",
        "",
        *_parameter_rows(res),
        "",
    ]
    h = res.hump
    if h["terms"] == 0:
        shape = "no hump: the lower friction is Coulomb plus viscous (no hump term lowers the equation error significantly)"
    elif h.get("monotone"):
        shape = f"{h['terms']} hump term(s), and the identified curve rises monotonically: no hump"
    else:
        a, b = h.get("falls_between_rad_s", [math.nan, math.nan])
        shape = (
            f"{h['terms']} hump term(s); the curve falls between {a:.3g} and {b:.3g} rad/s (negative damping)"
        )
    lines += ["## Friction curves", "", f"Lower disk: {shape}.", ""]
    if res.balance is not None:
        b = res.balance
        lines += [
            f"Steady-state balance of the upper disk alone (runs {', '.join(b.runs)}): k_m = {b.motor_constant:.4g}, "
            f"T_sup = {b.static:.4g}, b_up = {b.viscous:.4g}, k_theta = {b.string_stiffness:.4g} "
            "(a check on the joint fit, which uses every window of every run).",
            "",
        ]
    if "friction" in figs:
        lines += [
            "![friction curves](friction.png)",
            "",
            "Identified laws with their 95 % band; circles: the steady states of the constant-voltage runs.",
            "",
        ]
    lines += ["## Steady states of the constant-voltage runs", ""]
    lines += [
        "| run | u [V] | state | mean x3 [rad/s] | min x3 | max x3 | mean x1 [rad] |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in res.states:
        lines.append(
            f"| {s.run} | {s.voltage:g} | {s.kind} | {s.mean_speed:.4g} | {s.min_speed:.4g} | {s.max_speed:.4g} | {s.mean_twist:.4g} |"
        )
    sb = _stick_bracket(res)
    if not sb["bracketed"]:
        lines += [
            "",
            "The sweep does not bracket the stick boundary (no stuck run, or no moving one): add lower "
            "(or higher) constant voltages to check the identified boundary.",
        ]
    elif "identified_uc1_v" in sb:
        lines += [
            "",
            f"Stick boundary: stuck up to {sb['highest_stuck_v']:g} V, moving from {sb['lowest_moving_v']:g} V; "
            f"the identified model's (T_sup + T_sl)/k_m = {sb['identified_uc1_v']:.4g} V"
            + (" lies between them." if sb.get("consistent") else " does NOT lie between them."),
        ]
    lines.append("")
    if res.heldout:
        lines += [
            "## Held-out runs",
            "",
            "The model fitted without these runs, simulated on their input:",
            "",
        ]
        lines += [
            "| run | short-horizon speed RMS [rad/s] | noise floor [rad/s] | measured mean/min/max x3 | model mean/min/max x3 |",
            "|---|---|---|---|---|",
        ]
        for name, c in res.heldout.items():
            fm, fo = c.features_measured, c.features_model
            meas = f"{fm.mean_speed:.3g} / {fm.min_speed:.3g} / {fm.max_speed:.3g}" if fm else "-"
            mod = f"{fo.mean_speed:.3g} / {fo.min_speed:.3g} / {fo.max_speed:.3g}" if fo else "-"
            lines.append(
                f"| {res.dataset.run(name).label} | {c.short_speed_rms:.4g} | {c.floors.get('speed_rad_s', math.nan):.3g} | {meas} | {mod} |"
            )
        lines.append("")
        if "heldout" in figs:
            lines += ["![held-out runs](heldout.png)", ""]
    if "bifurcation" in figs:
        pts = ", ".join(f"{k} {v:.3g} V" for k, v in (bif or {}).get("points", {}).items())
        lines += [
            "## Bifurcation diagram of the identified model",
            "",
            f"Points: {pts or 'none in the range'}. Red: the data's steady states (mean, and min/max over 0.1 s)."
            + (
                f" The analysis covers the paper's model only: the effects {(bif or {})['effects_left_out']} are left out "
                "(as `drill-env bifurcation` and the env's regimes treat this rig file)."
                if (bif or {}).get("effects_left_out")
                else ""
            ),
            "",
            "![bifurcation diagram](bifurcation.png)",
            "",
        ]
    elif bif is not None and "error" in bif:
        lines += ["## Bifurcation diagram", "", f"Not drawn: {bif['error']}", ""]
    lines += [
        "## Use it",
        "",
        "<!-- excerpt -->",
        "```bash",
        "drill-env simulate --preset rig.yaml --voltage 2",
        "drill-env bifurcation --preset rig.yaml --out bifurcation/",
        *([] if res.effects else ["drill-env discrepancy DATASET --params rig.yaml --out discrepancy/"]),
        "drill-env tune --params rig.yaml --preset " + res.structure,
        "```",
        "",
        f"Fit: {res.fit.n_windows} equation-error windows, residual variance {res.fit.residual_variance:.3g} "
        "(1 is the noise floor); total time "
        f"{res.timings.get('total', math.nan):.1f} s.",
        "",
    ]
    return "\n".join(lines)
