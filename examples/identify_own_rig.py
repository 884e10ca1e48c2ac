"""Worked example of ``drill-env identify``: a rig far from the paper's, from recordings to controllers.

    python examples/identify_own_rig.py --out results/identify

1. The truth: a braked rig with every parameter between x0.5 and x2 of the paper's (the
   factors are in ``FACTORS`` below; the hump of the lower friction moves with them) plus a
   position-dependent friction at the lower disk (a library effect of the discrepancy
   workflow), written to ``OUT/truth/``.
2. ``drill-env synth --plan full --params OUT/truth/rig.yaml``: recordings on the
   identification plan (undithered 2000-count encoders, 500 Hz). The dataset (36 MB) goes
   to ``--work`` (a temporary folder by default), not under OUT.
3. ``drill-env identify DATA --known string_stiffness=...`` (the lab knows its string):
   ``OUT/identified/`` (rig.yaml, identification.json, report.md, figures).
4. (the discrepancy tests ran inside ``identify``: its structure search; see its report).
5. ``drill-env bifurcation --preset OUT/identified/rig.yaml`` (``OUT/bifurcation/``) and
   ``drill-env tune --params OUT/identified/rig.yaml`` (``OUT/controllers.yaml``); the tuned
   controllers then run, through the Python API, on an environment whose plant is the truth
   (effect included) at the voltages where the truth cycles (``OUT/controllers_on_truth.md``).

Every step prints the command it runs. ``OUT/summary.md`` collects the outcome.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

# The truth rig: the paper's braked rig with each parameter multiplied by these factors.
FACTORS = {
    "motor_constant": 0.6,
    "upper_inertia": 1.7,
    "upper_static_pos": 1.4,
    "upper_static_neg": 0.8,
    "upper_viscous_pos": 0.55,
    "upper_viscous_neg": 1.8,
    "lower_inertia": 0.5,
    "string_stiffness": 1.6,
    "lower_static": 0.7,
    "lower_viscous": 1.9,
    "lower_hump_1": 2.0,
    "lower_hump_2": 1.3,
    "lower_hump_rate_1": 0.5,
    "lower_hump_rate_2": 2.0,
}
EFFECT = "position_friction_lower"
MAGNITUDE = 0.12  # a1: once-per-revolution modulation of the lower static + Stribeck friction
SEED = 4
VOLTAGES = (1.0, 2.0, 3.0)  # [V] where the controllers are run on the truth
CONTROLLERS = ("pi_lower", "lqi", "lqi_angle_ff")


def run(cmd: list[str]) -> str:
    print("$ " + " ".join(shlex.quote(c) for c in cmd), flush=True)
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode not in (0,):
        sys.stderr.write(res.stdout[-3000:] + res.stderr[-3000:])
        raise SystemExit(f"step failed (exit {res.returncode}): {' '.join(cmd[:2])}")
    print(res.stdout.strip()[-1500:], flush=True)
    return res.stdout


def controllers_on_truth(out: Path, identified: Path, truth: Path) -> list[dict]:
    """The controllers tuned on the identified model, on the truth plant (Python API)."""
    import dataclasses

    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.gains import classical_controller
    from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env
    from drill_env.params import load_params

    model = load_params(identified)
    settings = EpisodeSettings()
    rows = []
    for u in VOLTAGES:
        env = make_env("brake", settings, params=str(truth))
        spec = dataclasses.replace(ControllerSpec.from_env(env), params=model)
        open_loop = classical_controller("open_loop", spec, "brake")
        ref = evaluate(open_loop, "brake", u, seed=0, settings=settings, env=env, open_loop_amplitude=0.0)
        for name in CONTROLLERS:
            ctrl = classical_controller(name, spec, "brake", gains_file=out / "controllers.yaml")
            m = evaluate(
                ctrl, "brake", u, seed=0, settings=settings, env=env, open_loop_amplitude=ref.amplitude
            )
            rows.append(
                {
                    "voltage": u,
                    "controller": name,
                    "open_loop_amplitude_rad_s": ref.amplitude,
                    "open_loop_stick_fraction": ref.stick_fraction,
                    "amplitude_rad_s": m.amplitude,
                    "suppression": m.suppression,
                    "stick_fraction": m.stick_fraction,
                    "rms_error_rad_s": m.rms_error,
                }
            )
            print(
                f"u = {u:g} V, {name}: open-loop amplitude {ref.amplitude:.3f} rad/s, closed loop "
                f"{m.amplitude:.3f} rad/s (suppression {m.suppression:.3f})",
                flush=True,
            )
        env.close()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("results/identify"))
    ap.add_argument("--work", type=Path, default=None, help="folder for the dataset (default: temporary)")
    args = ap.parse_args()
    from drill_env.outputs import atomic_write_text
    from drill_env.params import IDENTIFIED_PARAMETERS, load_params

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    base = load_params("brake")
    truth = base.replace(
        **{n: float(getattr(base, n)) * f for n, f in FACTORS.items()},
        name="example-truth",
        description="the worked example's truth: the paper's braked rig with every parameter x0.5-x2",
    )
    (out / "truth").mkdir(exist_ok=True)
    truth.to_yaml(out / "truth" / "rig.yaml")
    exe = [sys.executable, "-m", "drill_env.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        data = work / "data"
        run(
            [*exe, "synth", "--plan", "full", "--params", str(out / "truth" / "rig.yaml"), "--preset", "brake",
             "--effect", EFFECT, "--magnitude", str(MAGNITUDE), "--seed", str(SEED), "--angle-noise", "0",
             "--rate", "500", "--out", str(data), "--answer", str(out / "truth" / "answer.json")]
        )  # fmt: skip
        run(
            [*exe, "identify", str(data), "--out", str(out / "identified"),
             "--known", f"string_stiffness={truth.string_stiffness!r}"]
        )  # fmt: skip
        # the structure search of identify ran the discrepancy tests (its rounds are in the report)
    run(
        [*exe, "bifurcation", "--preset", str(out / "identified" / "rig.yaml"), "--umax", "5",
         "--out", str(out / "bifurcation"), "--no-check"]
    )  # fmt: skip
    run(
        [*exe, "tune", "--params", str(out / "identified" / "rig.yaml"), "--preset", "brake",
         "--out", str(out / "controllers.yaml")]
    )  # fmt: skip
    truth_with_effect = out / "truth" / "rig_with_effect.yaml"
    answer = json.loads((out / "truth" / "answer.json").read_text())
    truth.replace(**answer["model_effects"]).to_yaml(truth_with_effect)
    rows = controllers_on_truth(out, out / "identified" / "rig.yaml", truth_with_effect)
    atomic_write_text(out / "controllers_on_truth.json", json.dumps(rows, indent=2) + "\n")

    ident = json.loads((out / "identified" / "identification.json").read_text())
    lines = [
        "# Worked example: identify a rig far from the paper's",
        "",
        "Regenerate: `python examples/identify_own_rig.py --out results/identify`.",
        "",
        f"Truth (`truth/rig.yaml`): the paper's braked rig with every parameter x{min(FACTORS.values()):g}-"
        f"x{max(FACTORS.values()):g}, plus `{EFFECT}` of magnitude {MAGNITUDE:g} (`truth/answer.json`). "
        f"Recorded on the full plan (`drill-env identify --plan`), 500 Hz, undithered 2000-count encoders; "
        f"identified with the string stiffness given.",
        "",
        "| parameter | truth | identified | 95 % interval | truth inside |",
        "|---|---|---|---|---|",
    ]
    inside = total = 0
    for n in IDENTIFIED_PARAMETERS:
        p = ident["parameters"][n]
        t = float(getattr(truth, n))
        lo, hi = p["ci95"]
        ok = lo is not None and hi is not None and lo <= t <= hi
        if n != "string_stiffness":
            inside += ok
            total += 1
        ci = "-" if lo is None else f"[{lo:.4g}, {hi:.4g}]"
        lines.append(f"| {n} | {t:.4g} | {p['value']:.4g} | {ci} | {'yes' if ok else 'no'} |")
    search = ident.get("structure_search") or {}
    lines += [
        "",
        f"Truth inside the 95 % interval for {inside} of {total} parameters.",
        "",
        "The structure search of `drill-env identify` (discrepancy tests on the held-out runs after each "
        "fit; a named library effect re-fitted jointly with every base parameter; gap: held-out equation "
        "error per window, 1 the noise floor):",
        "",
        "| round | model tested | verdict | added | gap before | gap after |",
        "|---|---|---|---|---|---|",
    ]
    for r in search.get("rounds", []):
        after = "-" if r["gap_after"] is None else f"{r['gap_after']:.4g}"
        lines.append(
            f"| {r['round']} | {' + '.join(['base', *r['model_effects']])} | {r['verdict']} | "
            f"{', '.join(r['added']) or '-'} | {r['gap_before']:.4g} | {after} |"
        )
    lines += ["", f"Stopped: {search.get('stopped', '-')}.", ""]
    effects = ident.get("effects", {})
    if effects:
        lines += [
            "The final model's effect (in `identified/rig.yaml`'s `effects:` section) against the truth's:",
            "",
            "| effect | parameter | truth | identified | 95 % interval |",
            "|---|---|---|---|---|",
        ]
        for name, e in effects.items():
            for k, v in e["parameters"].items():
                t = answer["model_effects"].get(k)
                lo, hi = e["ci95"].get(k, [None, None])
                ci = "-" if lo is None or hi is None else f"[{lo:.4g}, {hi:.4g}]"
                lines.append(f"| {name} | {k} | {'-' if t is None else f'{t:.4g}'} | {v:.4g} | {ci} |")
        lines.append("")
    lines += [
        "",
        "Controllers tuned on the identified model (`drill-env tune --params identified/rig.yaml`, "
        "`controllers.yaml`), run on the truth plant with its effect (Python API: "
        "`make_env(..., params=truth/rig_with_effect.yaml)`, the controllers' model the identified one, "
        "with its effect):",
        "",
        "| u [V] | controller | open-loop amplitude [rad/s] | closed-loop amplitude [rad/s] | suppression | stick fraction |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['voltage']:g} | {r['controller']} | {r['open_loop_amplitude_rad_s']:.3f} | "
            f"{r['amplitude_rad_s']:.3f} | {r['suppression']:.3f} | {r['stick_fraction']:.3f} |"
        )
    lines += [
        "",
        "Files: `identified/` (rig.yaml, identification.json, report.md, friction.png, heldout.png, "
        "bifurcation.png), `bifurcation/` (the identified model's diagram), "
        "`controllers.yaml`, `controllers_on_truth.json`.",
        "",
    ]
    atomic_write_text(out / "summary.md", "\n".join(lines))
    print(f"wrote {out / 'summary.md'}")


if __name__ == "__main__":
    main()
