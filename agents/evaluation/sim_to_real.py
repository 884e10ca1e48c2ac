"""Sim-to-real: from measured data to a better controller, on a plant the nominal model lacks.

The worked example closes the loop the discrepancy workflow opens. A *truth* plant (the
preset plus a hidden effect and a few percent of parameter error, written as a rig YAML)
stands for the real rig; every step sees only what a user of the real rig would have:

1. *Measure*: :func:`drill_env.recordings.synth.make_dataset` records constant-voltage and
   quasi-random runs on the truth plant through the rig's encoders (no added angle noise:
   a real encoder's angle is the quantised true angle).
2. *Explain*: :func:`drill_env.discrepancy.workflow.run_discrepancy` compares the data with
   the nominal model and writes ``model.yaml``: the recalibrated parameters and the named
   effect (the *corrected model*).
3. *Redesign*: the classical controllers are tuned on the corrected model by the procedure
   of :mod:`drill_env.agents.controllers.tuning` (what ``drill-env tune --params model.yaml`` does); the LQI's
   gain schedule and the angle-locked feedforward's phase correction
   (:mod:`drill_env.agents.controllers.angle_feedforward`) are computed on it as well, and the
   effect it names is used: a position-dependent friction is fed forward as a function of the
   measured angle (:mod:`drill_env.agents.controllers.effect_feedforward`) by ``lqi`` and
   ``lqi_angle_ff`` (and by ``ppo_robust``'s base, its trained correction kept). The target
   speed the controllers regulate to is the design model's (what ``drill-env benchmark
   --design-params`` does: the *after* rows are ``benchmark --plant truth.yaml --design-params
   discrepancy/model.yaml --gains gains_corrected.yaml``).
4. *Score*: every controller, designed on the nominal model (*before*) and on the corrected
   model (*after*), runs on the truth plant through :func:`drill_env.agents.evaluation.episodes.evaluate`, the
   benchmark's one evaluation path, at the same voltages and seeds; the suppression is
   relative to the open-loop run on the truth plant at the same voltage and seed (as the
   benchmark's ``--plant``), with the benchmark's floor for "no cycle".

The truth is the built-in one (the preset, a hidden effect of the library, a few percent of
parameter error) or a plant file (``truth_file``, ``drill-env sim-to-real --truth``): its
effects, actuator delay and sensors are recorded and simulated as they are.

:func:`run_sim_to_real` writes ``truth.yaml`` and ``truth_answer.json`` (what the data were
made from; nothing downstream reads them), ``discrepancy/`` (the workflow's report,
``result.json`` and ``model.yaml``), ``gains_corrected.yaml`` (the tuned gains in the
format of ``configs/agents/controllers.yaml``, for ``drill-env benchmark --gains``),
``results.csv`` (one row per design x controller x voltage x seed; the benchmark's
columns), ``summary.md``, ``timeseries_<V>V.png`` and ``suppression.png``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.agents.evaluation.episodes import METRIC_COLUMNS, EpisodeSettings
from drill_env.outputs import save_figure

__all__ = [
    "CONTROLLERS",
    "DESIGNS",
    "SimToRealConfig",
    "SimToRealResult",
    "run_sim_to_real",
]

# the designs compared: on the preset's model, and on the discrepancy's corrected model
DESIGNS = ("nominal", "corrected")
# the classical controllers that are designed on a model (PI of the upper speed cannot damp
# the torsional mode for any gain, the lower-speed PI makes the cycles larger: drill_env.agents.controllers.tuning)
CONTROLLERS = ("torque_feedback", "lqi", "lqi_angle_ff", "ppo_robust")
# the controllers the example may compare: those designed on a model, and the residual policies
# on lqi_angle_ff (their base is redesigned, their trained correction kept)
ALLOWED = ("torque_feedback", "lqi", "lqi_angle_ff", "ppo_robust", "sac_robust")
VOLTAGES = (0.7, 0.85, 1.0, 1.25, 1.5)  # [V] where the rig turns near the torsional resonance
COLUMNS = ("design",) + METRIC_COLUMNS + ("plant",)
TRUTH = "truth"  # the plant's name in results.csv
# the paper's rig (Sec. 4.1): lower position friction a1 = 0.12; and parameters a few percent off
TRUTH_EFFECT = "position_friction_lower"
TRUTH_MAGNITUDE = 0.12
TRUTH_PARAMETER_ERRORS = {"motor_constant": 0.03, "lower_inertia": 0.05}
MAX_SEEDS = 20
ANGLE_LOCKED = "position_friction_lower"  # the effect the angle-locked feedforward is made for


def _default_synth():
    from drill_env.recordings.synth import SynthConfig

    return SynthConfig(preset="brake", angle_noise_std=0.0)


@dataclass(frozen=True)
class SimToRealConfig:
    """The worked example's truth plant, measurements, controllers and grid.

    ``parameter_errors`` are relative errors of identified parameters of the truth plant
    (:data:`drill_env.recordings.synth.IDENTIFIED` names); ``magnitude`` is the hidden
    effect's (for ``position_friction_lower``: a1, a2 = a1 U(0, 0.5), random phases).
    """

    effect: str = TRUTH_EFFECT
    magnitude: float = TRUTH_MAGNITUDE
    parameter_errors: Mapping[str, float] = field(default_factory=lambda: dict(TRUTH_PARAMETER_ERRORS))
    data_seed: int = 0  # seed of the truth's effect phases and of the recorded runs
    synth: Any = field(default_factory=_default_synth)  # a SynthConfig (its preset is the rig's)
    controllers: tuple[str, ...] = CONTROLLERS
    voltages: tuple[float, ...] = VOLTAGES  # [V]
    seeds: tuple[int, ...] = (0, 1)
    episode: EpisodeSettings = field(default_factory=EpisodeSettings)
    timeseries_voltage: float = 1.0  # [V]
    design_points: int = 12  # of drill_env.agents.controllers.tuning's design set (its default)
    tuning_grid: int = 7  # values per gain in drill_env.agents.controllers.tuning's grid search (its default)
    truth_file: str | None = None  # a plant file to take as the truth (effect, magnitude, errors unused)
    # the user vouched for learned controllers' policies from outside results/agents/ (from
    # $DRILL_ENV_AGENTS_DIR): they load (their files are code); not part of the result
    trust_policies: bool = False
    # the lab's model of its rig (a rig YAML, e.g. identify's rig.yaml): the nominal design, the
    # discrepancy's reference and the base of the built-in truth; None: the preset's model
    params_file: str | None = None

    def __post_init__(self) -> None:
        from drill_env.envs.task import VOLTAGE_LIMIT
        from drill_env.recordings.synth import HIDDEN_EFFECTS, IDENTIFIED, SynthConfig

        if not isinstance(self.synth, SynthConfig):
            raise ValueError(f"synth: expected a SynthConfig, got {type(self.synth).__name__}")
        # the closed loop runs the environment's sensors, which have no encoder eccentricity: a
        # measurement effect of the truth would be dropped there, so it is no truth here
        allowed = sorted(e for e, h in HIDDEN_EFFECTS.items() if e != "none" and h.kind == "plant")
        if self.effect not in allowed:
            raise ValueError(f"effect: {self.effect!r} is not one of {allowed}")
        for name, rel in self.parameter_errors.items():
            if name not in IDENTIFIED:
                raise ValueError(f"parameter_errors: {name!r} is not one of {list(IDENTIFIED)}")
            if isinstance(rel, bool) or not isinstance(rel, (int, float)) or not -0.3 <= rel <= 0.3:
                raise ValueError(f"parameter_errors.{name}: {rel!r} is outside the allowed range [-0.3, 0.3]")
        if isinstance(self.data_seed, bool) or not isinstance(self.data_seed, int) or self.data_seed < 0:
            raise ValueError(f"data_seed: expected an integer >= 0, got {self.data_seed!r}")
        if not self.controllers:
            raise ValueError(f"controllers: expected one or more of {list(CONTROLLERS)}")
        for c in self.controllers:
            if c not in ALLOWED:
                raise ValueError(f"controllers: {c!r} is not one of {list(ALLOWED)}")
        if self.truth_file is not None:
            from drill_env.plant_file import read_plant_file, without_measurement

            # a ParameterError naming the field
            without_measurement(read_plant_file(self.truth_file), "sim-to-real's closed loop")
            object.__setattr__(self, "truth_file", str(self.truth_file))
        if self.params_file is not None:
            object.__setattr__(self, "params_file", str(self.params_file))
            try:
                self.nominal_model()
            except ValueError as exc:
                raise ValueError(f"params_file: {self.params_file}: {exc}") from None
        uc1 = self.nominal_model().uc1
        if not self.voltages:
            raise ValueError("voltages: expected at least one voltage")
        for v in (*self.voltages, self.timeseries_voltage):
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not (math.isfinite(v) and uc1 < v <= VOLTAGE_LIMIT)
            ):
                raise ValueError(
                    f"voltages: {v!r} V is outside the allowed range ({uc1:.4g}, {VOLTAGE_LIMIT:g}] V"
                )
        if not self.seeds or len(self.seeds) > MAX_SEEDS:
            raise ValueError(f"seeds: expected 1 to {MAX_SEEDS} seeds, got {len(self.seeds)}")
        for s in self.seeds:
            if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
                raise ValueError(f"seeds: {s!r} is not an integer >= 0")
        for name in ("design_points", "tuning_grid"):
            n = getattr(self, name)
            if isinstance(n, bool) or not isinstance(n, int) or not 2 <= n <= 50:
                raise ValueError(f"{name}: {n!r} is outside the allowed range [2, 50]")
        object.__setattr__(self, "parameter_errors", {k: float(v) for k, v in self.parameter_errors.items()})
        object.__setattr__(self, "controllers", tuple(dict.fromkeys(self.controllers)))
        object.__setattr__(self, "voltages", tuple(float(v) for v in self.voltages))
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))

    @property
    def preset(self) -> str:
        return self.synth.preset

    def nominal_model(self):
        """The model the *before* design is built on: ``params_file``'s, else the preset's."""
        from drill_env.params import load_params

        return load_params(self.params_file if self.params_file is not None else self.preset)

    def to_dict(self) -> dict[str, Any]:
        return {
            "preset": self.preset,
            "effect": self.effect,
            "magnitude": self.magnitude,
            "parameter_errors": dict(self.parameter_errors),
            "data_seed": self.data_seed,
            "synth": dataclasses.asdict(self.synth),
            "controllers": list(self.controllers),
            "voltages": list(self.voltages),
            "seeds": list(self.seeds),
            "episode": self.episode.to_dict(),
            "timeseries_voltage": self.timeseries_voltage,
            "design_points": self.design_points,
            "tuning_grid": self.tuning_grid,
            "truth_file": self.truth_file,
            "params_file": self.params_file,
        }


@dataclass
class SimToRealResult:
    """What :func:`run_sim_to_real` found and wrote."""

    config: SimToRealConfig
    truth: Any  # RigParams of the truth plant (effects included)
    answer: dict[str, Any]  # the synthetic data's answer (effect, parameters)
    discrepancy: dict[str, Any]  # the workflow's result.json
    corrected: Any  # RigParams of the corrected model (the nominal one if nothing changed)
    gains: dict[str, dict[str, dict[str, float]]]  # design -> controller -> gains
    decay_rates: dict[str, dict[str, float]]  # design -> controller -> worst decay rate [1/s]
    rows: list[dict[str, Any]]
    files: list[Path]
    timings: dict[str, float]
    # design -> voltage -> phase of the feedforward's G_1 against the truth's [deg]
    phase_errors: dict[str, dict[float, float]] = field(default_factory=dict)
    # voltage -> the identified effect's feedforward on the corrected model: target speed [rad/s],
    # |C_h| of the lower and upper angle [V], decay rate of the rotation with it [1/s]
    effect_feedforward: dict[float, dict[str, Any]] = field(default_factory=dict)

    def to_pandas(self):
        import pandas as pd

        return pd.DataFrame(self.rows, columns=list(COLUMNS))


def _truth_overrides(cfg: SimToRealConfig) -> dict[str, float]:
    """The built-in truth's parameters: the nominal model's with ``cfg.parameter_errors``
    (every parameter set when the nominal model is a rig file, not the preset)."""
    from dataclasses import asdict

    from drill_env.recordings.synth import IDENTIFIED

    base = cfg.nominal_model()
    names = IDENTIFIED if cfg.params_file is not None else tuple(cfg.parameter_errors)
    out = {n: float(getattr(base, n)) * (1.0 + cfg.parameter_errors.get(n, 0.0)) for n in names}
    if cfg.params_file is not None:  # an effect the rig's model already has stays in the truth
        out.update({k: float(v) for k, v in asdict(base.effects).items() if v != 0.0})
    return out


def tuned_kinds(controllers: Sequence[str]) -> tuple[str, ...]:
    """The tuned controllers whose gains ``controllers`` use (``lqi_angle_ff``: the LQI's)."""
    from drill_env.agents.controllers.gains import BUILT_ON
    from drill_env.agents.registry import LEARNED

    return tuple(dict.fromkeys(BUILT_ON.get(c, c) for c in controllers if c not in LEARNED))


def _tuned_gains(model, source: str, cfg: SimToRealConfig, control_dt: float, progress) -> dict[str, Any]:
    """The gains file of ``drill-env tune --params``: :func:`drill_env.agents.controllers.tuning.tune` on ``model``."""
    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.tuning import design_points, tune, tune_all

    data = tune_all(presets=(), control_dt=control_dt)
    data["design_model"] = {"preset": cfg.preset, "params": source, "name": model.name}
    if (cfg.design_points, cfg.tuning_grid) != (12, 7):
        data["design_model"].update(design_points=cfg.design_points, grid=cfg.tuning_grid)
    spec = ControllerSpec(params=model, control_dt=control_dt)
    points = design_points(spec.params, n=cfg.design_points)  # the linear model: no effects
    data["presets"][cfg.preset] = {}
    for kind in tuned_kinds(cfg.controllers):
        progress(f"      tuning {kind} on the corrected model")
        data["presets"][cfg.preset][kind] = tune(kind, spec, points=points, grid=cfg.tuning_grid).to_dict()
    return data


def _open_loop_run(env, preset: str, voltage: float, seed: int, episode: EpisodeSettings) -> dict[str, Any]:
    """The open-loop run on the truth plant; its amplitude is the reference of the suppression,
    as the benchmark's ``--plant`` (0 below the benchmark's floor: no cycle, suppression NaN)."""
    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.open_loop import OpenLoop
    from drill_env.agents.evaluation.benchmark import OPEN_LOOP_FLOOR
    from drill_env.agents.evaluation.episodes import evaluate, open_loop_regime, suppression

    m = evaluate(
        OpenLoop(ControllerSpec.from_env(env)),
        preset,
        voltage,
        seed,
        episode,
        name="open_loop",
        env=env,
        open_loop_amplitude=0.0,
    ).as_dict()
    ref = m["amplitude"] if m["amplitude"] >= OPEN_LOOP_FLOOR else 0.0
    regime = open_loop_regime(ref, m["stick_fraction"])
    m.update(
        open_loop_amplitude=ref, suppression=suppression(m["amplitude"], ref), plant_open_loop_regime=regime
    )
    return m


# what ``run_sim_to_real`` writes (a folder of these from before folders had markers is its own)
SIM_TO_REAL_FILES = (
    "summary.md",
    "results.csv",
    "config.json",
    "gains_corrected.yaml",
    "truth.yaml",
    "truth_answer.json",
    "suppression.png",
    "timeseries_*V.png",
)


def run_sim_to_real(
    out: str | Path,
    config: SimToRealConfig | None = None,
    *,
    data_dir: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
) -> SimToRealResult:
    """Run the worked example (see the module docstring) and write it to ``out``.

    ``data_dir`` keeps the synthetic dataset there (default: a temporary folder, removed at
    the end; the dataset is tens of MB). ``progress`` receives one line per stage.
    """
    from drill_env.outputs import check_command_folder, check_new_folder, command_folder

    cfg = config or SimToRealConfig()
    say = progress or (lambda line: None)
    out = Path(out)
    check_command_folder(out, "sim-to-real", "out", own=SIM_TO_REAL_FILES)
    if data_dir is not None:  # a new dataset, never mixed with the runs of another one
        check_new_folder(data_dir, "data_dir", what="dataset")
    with (
        command_folder(out, "sim-to-real", "out", own=SIM_TO_REAL_FILES),
        tempfile.TemporaryDirectory(prefix="sim_to_real_") as tmp,
    ):
        data = Path(data_dir) if data_dir is not None else Path(tmp) / "data"
        return _run(out, cfg, data, say)


def _run(out: Path, cfg: SimToRealConfig, data: Path, say: Callable[[str], None]) -> SimToRealResult:
    import yaml

    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.gains import gains_path, load_gains
    from drill_env.agents.evaluation.episodes import evaluate, make_env, run_episode
    from drill_env.agents.registry import build_controller, observation_version
    from drill_env.discrepancy.workflow import run_discrepancy
    from drill_env.outputs import atomic_write_text
    from drill_env.recordings.synth import make_dataset, make_plant_dataset, write_synthetic

    preset = cfg.preset
    timings: dict[str, float] = {}
    files: list[Path] = []
    # 1. measure the truth plant
    t0 = time.perf_counter()
    n_runs = len(cfg.synth.voltages) + cfg.synth.random_runs
    plant = None
    if cfg.truth_file is not None:
        from drill_env.agents.evaluation.plants import Plant

        plant = Plant.from_path(cfg.truth_file)
        synth_cfg = dataclasses.replace(
            cfg.synth,
            encoder_counts_per_rev=int(plant.sensors.get("counts_per_rev", cfg.synth.encoder_counts_per_rev)),
            angle_noise_std=float(plant.sensors.get("angle_noise_std", cfg.synth.angle_noise_std)),
        )
        delay = plant.sensors.get("delay_samples", 0) / float(plant.sensors.get("sample_rate_hz", 1000.0))
        say(f"[1/5] recording {n_runs} runs on the truth plant {cfg.truth_file}")
        synth = make_plant_dataset(
            plant.params, seed=cfg.data_seed, config=synth_cfg, delay_s=delay, source=cfg.truth_file
        )
        truth = plant.params
        plant.to_file(out / "truth.yaml", preset)
    else:
        say(
            f"[1/5] recording {n_runs} runs on the truth plant ({cfg.effect}, {cfg.magnitude:g}; "
            + ", ".join(f"{k} {v:+.0%}" for k, v in cfg.parameter_errors.items())
            + ")"
        )
        synth = make_dataset(
            cfg.effect,
            seed=cfg.data_seed,
            magnitude=cfg.magnitude,
            config=cfg.synth,
            truth_overrides=_truth_overrides(cfg),
        )
        truth = synth.truth.replace(
            name="truth", description="sim-to-real truth plant (drill-env sim-to-real)"
        )
        truth.to_yaml(out / "truth.yaml")
    write_synthetic(synth, data, out / "truth_answer.json", preset=preset)
    files += [out / "truth.yaml", out / "truth_answer.json"]
    timings["measure"] = time.perf_counter() - t0

    # 2. the discrepancy workflow on the measurements alone
    t0 = time.perf_counter()
    say(f"[2/5] discrepancy workflow on {n_runs} runs")
    nominal = cfg.nominal_model()
    disc = run_discrepancy(
        data, out / "discrepancy", seed=0, params=None if cfg.params_file is None else nominal
    )
    result = json.loads((out / "discrepancy" / "result.json").read_text())
    model_file = out / "discrepancy" / "model.yaml"
    corrected = nominal
    if model_file.is_file():
        from drill_env.plant_file import read_plant_file

        found = read_plant_file(model_file)  # its measurement section (an eccentric encoder), if any,
        corrected = found.params  # is how the truth's angles were read, not what a design needs
        if found.measurement.active:
            from drill_env.measurement import measurement_text

            say(
                "      the corrected model's measurement section is no part of the design (the plant is): "
                + measurement_text(found.measurement)
            )
    say(f"      {disc.verdict_line()}")
    files += [out / "discrepancy" / "result.json", out / "discrepancy" / "report.md"]
    timings["discrepancy"] = time.perf_counter() - t0

    # 3. the designs: the committed nominal gains, and gains tuned on the corrected model
    t0 = time.perf_counter()
    say("[3/5] design on the corrected model")
    probe = make_env(preset, cfg.episode)
    control_dt = float(probe.unwrapped.control_dt)  # the environment's, as the benchmark tunes for
    probe.close()
    tuned = _tuned_gains(corrected, "discrepancy/model.yaml", cfg, control_dt, say)
    header = (
        "# Gains of the classical controllers tuned on the corrected model discrepancy/model.yaml,\n"
        "# written by `drill-env sim-to-real` (agents/controllers/tuning.py; as `drill-env tune --params`).\n"
    )
    gains_file = out / "gains_corrected.yaml"
    atomic_write_text(gains_file, header + yaml.safe_dump(tuned, sort_keys=False, width=100))
    files.append(gains_file)
    if cfg.params_file is None:
        nominal_gains = load_gains()["presets"][preset]
        nominal_gains_file = str(gains_path())
    else:  # the lab's model: its controllers are tuned on it as well (drill-env tune --params)
        say("      tuning on the nominal model " + cfg.params_file)
        own = _tuned_gains(nominal, cfg.params_file, cfg, control_dt, say)
        nominal_gains = own["presets"][preset]
        gains_nominal = out / "gains_nominal.yaml"
        atomic_write_text(
            gains_nominal,
            f"# Gains of the classical controllers tuned on the nominal model {cfg.params_file},\n"
            "# written by `drill-env sim-to-real --params` (as `drill-env tune --params`).\n"
            + yaml.safe_dump(own, sort_keys=False, width=100),
        )
        files.append(gains_nominal)
        nominal_gains_file = str(gains_nominal)
    design_of = {
        "nominal": (nominal, nominal_gains_file),
        "corrected": (corrected, str(gains_file)),
    }
    gains = {
        "nominal": {k: dict(nominal_gains[k]["gains"]) for k in tuned_kinds(cfg.controllers)},
        "corrected": {k: dict(tuned["presets"][preset][k]["gains"]) for k in tuned_kinds(cfg.controllers)},
    }
    decay = {
        "nominal": {k: float(nominal_gains[k]["worst_decay_rate"]) for k in tuned_kinds(cfg.controllers)},
        "corrected": {
            k: float(tuned["presets"][preset][k]["worst_decay_rate"]) for k in tuned_kinds(cfg.controllers)
        },
    }
    timings["design"] = time.perf_counter() - t0

    # 4. every design on the truth plant, through the benchmark's evaluation path: each design's
    # controllers are built on its model (benchmark --design-params), and the task (target speed)
    # is that model's; the truth is only simulated
    t0 = time.perf_counter()
    version = max(observation_version(c, preset) for c in cfg.controllers)
    overrides = plant.env_overrides() if plant is not None else None
    design_model = {"nominal": None if cfg.params_file is None else nominal, "corrected": corrected}
    envs = {
        d: make_env(preset, cfg.episode, version, params=truth, overrides=overrides, design_params=m)
        for d, m in design_model.items()
    }
    rows: list[dict[str, Any]] = []
    traces: dict[tuple[str, str], Any] = {}
    try:
        ctrls = {}
        for d, (_, g) in design_of.items():
            design_env = make_env(preset, cfg.episode, version, design_params=design_model[d])
            try:
                for c in cfg.controllers:
                    ctrls[(d, c)] = build_controller(
                        c, design_env, preset, gains_file=g, trusted=cfg.trust_policies
                    )
            finally:
                design_env.close()
        n_total = len(cfg.voltages) * len(cfg.seeds)
        say(
            f"[4/5] {len(cfg.controllers)} controllers x {len(DESIGNS)} designs and the open loop x "
            f"{len(cfg.voltages)} voltages x {len(cfg.seeds)} seeds on the truth plant"
        )
        open_loop = _open_loop(ControllerSpec.from_env(envs["nominal"]))
        for i, (v, s) in enumerate((v, s) for v in cfg.voltages for s in cfg.seeds):
            ol = _open_loop_run(envs["nominal"], preset, v, s, cfg.episode)
            ref = ol["open_loop_amplitude"]
            rows.append({"design": "-", **ol, "plant": TRUTH})
            for (d, c), ctrl in ctrls.items():
                m = evaluate(
                    ctrl,
                    preset,
                    v,
                    s,
                    cfg.episode,
                    name=c,
                    env=envs[d],
                    open_loop_amplitude=ref,
                    plant_open_loop_regime=ol["plant_open_loop_regime"],
                )
                rows.append({"design": d, **m.as_dict(), "plant": TRUTH})
            done = rows[-len(ctrls) :]
            say(
                f"      {i + 1}/{n_total}: {v:g} V seed {s}: suppression "
                + ", ".join(f"{r['controller']}/{r['design']} {r['suppression']:.2f}" for r in done)
            )
        # one run per design at the time-series voltage, its 1 kHz samples kept
        n = cfg.episode.n_steps(control_dt)
        opts = {"nominal_voltage": cfg.timeseries_voltage}
        traces[("-", "open_loop")] = run_episode(
            envs["nominal"], open_loop, seed=cfg.seeds[0], n_steps=n, options=opts, window_steps=n
        )
        for (d, c), ctrl in ctrls.items():
            traces[(d, c)] = run_episode(
                envs[d], ctrl, seed=cfg.seeds[0], n_steps=n, options=opts, window_steps=n
            )
    finally:
        for e in envs.values():
            e.close()
    timings["evaluate"] = time.perf_counter() - t0
    phases = _phase_errors(ctrls, design_of, truth, rows, cfg)
    effect_ff = _effect_feedforward(ctrls, corrected, cfg)

    # 5. the report
    say("[5/5] summary and figures")
    res = SimToRealResult(
        config=cfg,
        truth=truth,
        answer=synth.answer,
        discrepancy=result,
        corrected=corrected,
        gains=gains,
        decay_rates=decay,
        rows=rows,
        files=files,
        timings=timings,
        phase_errors=phases,
        effect_feedforward=effect_ff,
    )
    df = res.to_pandas()
    csv = out / "results.csv"
    atomic_write_text(csv, df.to_csv(index=False, float_format="%.6g"))
    files.append(csv)
    files.append(_timeseries_figure(traces, cfg, out))
    files.append(_suppression_figure(df, cfg, out))
    summary = out / "summary.md"
    atomic_write_text(summary, summary_markdown(res))
    files.append(summary)
    rec = out / "config.json"
    atomic_write_text(rec, json.dumps({**cfg.to_dict(), "timings_s": timings}, indent=2) + "\n")
    files.append(rec)
    return res


def _open_loop(spec):
    from drill_env.agents.controllers.open_loop import OpenLoop

    return OpenLoop(spec)


# -- report ------------------------------------------------------------------------------------

LINE = {"nominal": "--", "corrected": "-"}
LABEL = {
    "nominal": "designed on the nominal model (before)",
    "corrected": "designed on the corrected model (after)",
}


COINCIDE = 0.02  # [rad/s] before and after closer than this everywhere are said to coincide
# the figures: at most FIGURE_WIDTH wide, no text below FONT (legible where the docs draw a
# figure, 724 px wide: drill_env._figures' size rule)
FIGURE_WIDTH = 8.0  # [in]
FONT = 9.0  # [pt]


def _legend_below(fig, handles: list, ncol: int = 1) -> None:  # noqa: ANN001
    """One legend centred below the panels, the panels laid out above its measured height."""
    from drill_env._figures import renderer

    leg = fig.legend(handles=handles, loc="lower center", ncol=ncol, fontsize=FONT, frameon=False)
    height = leg.get_window_extent(renderer(fig)).height / (fig.dpi * fig.get_figheight())
    fig.tight_layout(rect=(0, height + 0.01, 1, 1))


def _timeseries_figure(traces: Mapping[tuple[str, str], Any], cfg: SimToRealConfig, out: Path) -> Path:
    from matplotlib.lines import Line2D

    from drill_env._figures import subplots
    from drill_env.agents.evaluation.robustness import COLORS

    ctrls = cfg.controllers
    fig, axes = subplots(
        len(ctrls), 1, figsize=(FIGURE_WIDTH, 2.1 * len(ctrls) + 1.6), sharex=True, sharey=True, squeeze=False
    )
    ol = traces[("-", "open_loop")]
    t_on = float(ol.t[0]) - float(ol.t[1] - ol.t[0]) if ol.t.size > 1 else 0.0
    for ax, c in zip(axes[:, 0], ctrls, strict=True):
        ax.plot(ol.window_t - t_on, ol.window_lower_speed, color="0.7", lw=0.8)
        before, after = traces[("nominal", c)], traces[("corrected", c)]
        # before: wide, dashed, black, under; after: thin, solid, in the controller's colour
        ax.plot(before.window_t - t_on, before.window_lower_speed, "--", color="k", lw=2.0, alpha=0.55)
        ax.plot(after.window_t - t_on, after.window_lower_speed, "-", color=COLORS.get(c, "C0"), lw=1.0)
        for tr, style in ((before, (0, (4, 2))), (after, "-")):
            ax.axhline(float(tr.reset_info["target_speed"]), color="0.3", ls=style, lw=0.6)
        n = min(before.window_lower_speed.size, after.window_lower_speed.size)
        gap = (
            float(np.max(np.abs(before.window_lower_speed[:n] - after.window_lower_speed[:n]))) if n else 0.0
        )
        if gap < COINCIDE:
            ax.text(
                0.99,
                0.95,
                f"before and after coincide (largest difference {gap:.3f} rad/s)",
                transform=ax.transAxes,
                ha="right",
                va="top",
                fontsize=FONT,
                bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
            )
        ax.set_title(c, fontsize=FONT + 1, loc="left")
        ax.set_ylabel("lower-disk speed\n[rad/s]", fontsize=FONT)
        ax.tick_params(labelsize=FONT)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time since the controller was switched on [s]", fontsize=FONT)
    handles = [
        Line2D([], [], color="0.7", lw=0.8, label="open loop"),
        Line2D([], [], ls="--", color="k", lw=2.0, alpha=0.55, label=LABEL["nominal"]),
        Line2D([], [], color="C0", lw=1.0, label=LABEL["corrected"] + " (controller's colour)"),
        Line2D([], [], color="0.3", ls=(0, (4, 2)), lw=0.6, label="target speed, nominal model"),
        Line2D([], [], color="0.3", ls="-", lw=0.6, label="target speed, corrected model"),
    ]
    what = (
        f"plant file {Path(cfg.truth_file).name}"
        if cfg.truth_file
        else f"{cfg.effect} {cfg.magnitude:g}, parameter errors"
    )
    fig.suptitle(
        f"Truth plant ({what}) at {cfg.timeseries_voltage:g} V, seed {cfg.seeds[0]}", fontsize=FONT + 1
    )
    _legend_below(fig, handles, ncol=2)
    path = out / f"timeseries_{cfg.timeseries_voltage:g}V.png"
    save_figure(fig, path, dpi=110)
    return path


def _suppression_figure(df, cfg: SimToRealConfig, out: Path) -> Path:
    from matplotlib.lines import Line2D

    from drill_env._figures import subplots
    from drill_env.agents.evaluation.robustness import COLORS

    ctrls = cfg.controllers
    # one row per controller: its suppression (left) and RMS speed error (right)
    fig, axes = subplots(
        len(ctrls),
        2,
        figsize=(FIGURE_WIDTH, 1.9 * len(ctrls) + 1.9),
        sharex=True,
        sharey="col",
        squeeze=False,
    )
    for i, c in enumerate(ctrls):
        for j, metric in enumerate(("suppression", "rms_error")):
            ax = axes[i, j]
            for d, marker, off in zip(DESIGNS, ("o", "s"), (-0.012, 0.012), strict=True):
                g = df[(df.controller == c) & (df.design == d)].groupby("voltage")[metric]
                mean, lo, hi = g.mean(), g.min(), g.max()
                ax.errorbar(
                    mean.index + off,  # side by side where they coincide
                    mean.values,
                    yerr=[mean.values - lo.values, hi.values - mean.values],
                    fmt=LINE[d] + marker,
                    color=COLORS.get(c, "C0") if d == "corrected" else "k",
                    mfc="none" if d == "nominal" else None,
                    ms=6 if d == "nominal" else 4,
                    capsize=2,
                    lw=1.0,
                )
            if metric == "suppression":
                ax.axhline(1.0, color="0.7", lw=0.6)
                ax.axhline(0.0, color="0.7", lw=0.6)
                ax.set_ylabel("suppression [-]", fontsize=FONT)
                ax.set_title(c, fontsize=FONT + 1, loc="left", color=COLORS.get(c, "k"))
            else:
                ax.set_yscale("log")
                ax.set_ylabel("RMS speed error\n[rad/s] (log)", fontsize=FONT)
            if i == len(ctrls) - 1:
                ax.set_xlabel("nominal voltage [V]", fontsize=FONT)
            ax.tick_params(labelsize=FONT)
            ax.grid(alpha=0.3)
    handles = [
        Line2D([], [], ls="--", marker="o", mfc="none", color="k", label=LABEL["nominal"]),
        Line2D([], [], ls="-", marker="s", color="C0", label=LABEL["corrected"] + " (controller's colour)"),
    ]
    n = len(cfg.seeds)
    fig.suptitle(
        f"On the truth plant: mean over {n} seed{'s' if n > 1 else ''} (bars: min-max; before and\n"
        "after drawn side by side); suppression against the open loop on the same plant",
        fontsize=FONT + 1,
    )
    _legend_below(fig, handles)
    path = out / "suppression.png"
    save_figure(fig, path, dpi=110)
    return path


def _fmt(x: float, digits: int = 3) -> str:
    return "-" if x is None or not math.isfinite(float(x)) else f"{float(x):.{digits}f}"


def summary_markdown(res: SimToRealResult) -> str:
    """``summary.md``: what the discrepancy found, what changed in the design, before/after."""

    cfg = res.config
    nominal = cfg.nominal_model()
    disc = res.discrepancy
    eff_fields = res.answer.get("model_effects", {})
    if cfg.truth_file:
        errs = res.answer.get("parameter_errors", {})
        what = (
            f"The plant file `{Path(cfg.truth_file).name}` (copied to `truth.yaml`): effects "
            + (", ".join(f"{k} = {v:.4g}" for k, v in eff_fields.items()) or "none")
            + "; parameters off the nominal model: "
            + (", ".join(f"{k} {v:+.1%}" for k, v in errs.items()) or "none")
            + f"; actuator delay {1000 * float(res.answer.get('actuator_delay', 0.0)):g} ms. It was recorded like the rig: "
        )
    else:
        base = (
            f"The `{cfg.preset}` preset" if cfg.params_file is None else f"The rig model `{cfg.params_file}`"
        )
        what = (
            f"{base} with the hidden effect `{cfg.effect}` ("
            + ", ".join(f"{k} = {v:.4g}" for k, v in eff_fields.items())
            + ") and the parameter errors "
            + ", ".join(f"{k} {v:+.0%}" for k, v in cfg.parameter_errors.items())
            + " (`truth.yaml`). It was recorded like the rig: "
        )
    lines = [
        "# Sim-to-real: from measured data to a better controller",
        "",
        "Regenerate with `drill-env sim-to-real --out results/sim_to_real` (written by "
        "`agents/evaluation/sim_to_real.py`; never edited by hand).",
        "",
        "## The truth plant",
        "",
        what
        + f"{len(cfg.synth.voltages)} constant-voltage runs ({', '.join(f'{v:g}' for v in cfg.synth.voltages)} V) "
        f"and {cfg.synth.random_runs} quasi-random run(s), {cfg.synth.duration_s:g} s each at "
        f"{cfg.synth.sample_rate_hz:g} Hz, {res.answer.get('design', {}).get('encoder_counts_per_rev', cfg.synth.encoder_counts_per_rev)} counts/rev, angle noise "
        f"{res.answer.get('design', {}).get('angle_noise_std', cfg.synth.angle_noise_std):g} rad.",
        "",
        "## What the discrepancy workflow found",
        "",
        f"Verdict: **{disc['effect']}** (confidence {disc['confidence']:.2f}); named effects: "
        + (", ".join(f"`{e}`" for e in disc.get("effects", [])) or "none")
        + ".",
        "",
    ]
    if disc.get("parameters"):
        lines += [
            "Fitted effect parameters against the truth:",
            "",
            "| field | fitted | truth |",
            "|---|---|---|",
        ]
        for k, v in disc["parameters"].items():
            tv = eff_fields.get(k)
            lines.append(f"| `{k}` | {v:.4g} | {'-' if tv is None else f'{tv:.4g}'} |")
        lines.append("")
    truth_vals = res.answer.get("parameters_at_nominal_string_stiffness", {})
    if cfg.params_file is not None:  # the answer's scale is the preset's; the nominal here is the rig's
        from drill_env.recordings.synth import IDENTIFIED

        c = nominal.string_stiffness / res.truth.string_stiffness
        truth_vals = {
            n: float(getattr(res.truth, n)) * (1.0 if n.startswith("lower_hump_rate") else c)
            for n in IDENTIFIED
        }
    names = list(dict.fromkeys(list(disc.get("recalibrated", {})) + list(cfg.parameter_errors)))
    lines += [
        "Recalibrated parameters (the data fix torque ratios only; the string stiffness is kept "
        "nominal and sets the scale, so the truth is given at the nominal string stiffness):",
        "",
        "| parameter | nominal | recalibrated | 95 % interval | truth | error of the recalibrated value |",
        "|---|---|---|---|---|---|",
    ]
    for n in names:
        rec = disc.get("recalibrated", {}).get(n)
        nom = float(getattr(nominal, n))
        tv = truth_vals.get(n, float(getattr(res.truth, n)))
        val = float(getattr(res.corrected, n))
        ci = f"[{rec['ci95'][0]:.4g}, {rec['ci95'][1]:.4g}]" if rec and rec.get("ci95") else "(not moved)"
        lines.append(
            f"| `{n}` | {nom:.4g} | {val:.4g} ({val / nom - 1:+.1%}) | {ci} | {tv:.4g} ({tv / nom - 1:+.1%}) | "
            f"{val / tv - 1:+.1%} |"
        )
    lines += [
        "",
        "## What changed in the design",
        "",
        "The classical controllers were tuned on the corrected model (`discrepancy/model.yaml`) by the "
        "procedure of `agents/controllers/tuning.py`, as `drill-env tune --params` does (`gains_corrected.yaml`); "
        "the LQI's gain schedule and the angle-locked feedforward's phase correction are computed on "
        "that model too, and the target speed the controllers regulate to is its own. The linearised "
        "model has the recalibrated parameters but not the effect (a friction that varies with the "
        "disk's angle is no parameter of a linear model); the effect is used as what it is, a known "
        "function of the measured angle: `lqi` and `lqi_angle_ff` designed on the corrected model add "
        "its feedforward (`agents/controllers/effect_feedforward.py`), and so does the base of a "
        "residual policy (`ppo_robust`: its trained correction is kept, its `lqi_angle_ff` base is "
        "designed on the corrected model).",
        "",
        "| controller | gains, nominal design | gains, corrected design | worst decay rate nominal / corrected design [1/s] |",
        "|---|---|---|---|",
    ]
    for k in tuned_kinds(cfg.controllers):
        g0 = ", ".join(f"{n} = {v:.4g}" for n, v in res.gains["nominal"][k].items())
        g1 = ", ".join(f"{n} = {v:.4g}" for n, v in res.gains["corrected"][k].items())
        lines.append(
            f"| `{k}` | {g0} | {g1} | {res.decay_rates['nominal'][k]:.3f} / {res.decay_rates['corrected'][k]:.3f} |"
        )
    lines += ["", "`lqi_angle_ff` has no gains of its own: it is the LQI above plus the feedforward.", ""]
    if res.effect_feedforward:
        lines += [
            "The identified effect's feedforward on the corrected model, per voltage: the target speed, "
            "the amplitude |C_h| of its harmonics of the lower (and upper) angle, and the decay rate of "
            "the rotation with it, from the Floquet multipliers of the periodic linearisation over one "
            "revolution (> 0: stable; `effect_feedforward.orbit_decay_rate`):",
            "",
            "| voltage [V] | target speed [rad/s] | lower \\|C_1\\|, \\|C_2\\| [V] | upper \\|C_1\\|, \\|C_2\\| [V] | decay rate [1/s] |",
            "|---|---|---|---|---|",
        ]
        for v, e in res.effect_feedforward.items():
            lines.append(
                f"| {v:g} | {e['speed']:.3f} | {e['lower'][0]:.3f}, {e['lower'][1]:.3f} | "
                f"{e['upper'][0]:.3f}, {e['upper'][1]:.3f} | {e['decay_rate']:.3f} |"
            )
        lines.append("")
    lines += _before_after(res)
    lines += [
        "",
        f"Figures: `timeseries_{cfg.timeseries_voltage:g}V.png` (lower-disk speed at "
        f"{cfg.timeseries_voltage:g} V, seed {cfg.seeds[0]}, before and after, with the open loop), "
        "`suppression.png` (suppression and RMS speed error against voltage). Every run: `results.csv`; "
        "the discrepancy report: `discrepancy/report.md`.",
        "",
        "Wall time [s]: " + ", ".join(f"{k} {v:.0f}" for k, v in res.timings.items()) + ".",
        "",
    ]
    return "\n".join(lines)


def _effect_feedforward(ctrls, corrected, cfg: SimToRealConfig) -> dict[float, dict[str, Any]]:
    """Per voltage, the corrected design's feedforward of the identified position friction
    (:mod:`drill_env.agents.controllers.effect_feedforward`) and the decay rate of the rotation
    with it on the corrected model; empty where the model names no such effect."""
    from drill_env.envs.task import equilibrium_speed, nominal_params

    ctrl = ctrls.get(("corrected", "lqi")) or ctrls.get(("corrected", "lqi_angle_ff"))
    effect = getattr(ctrl, "effect", None)
    if effect is None:
        return {}
    out = {}
    for v in cfg.voltages:
        w = equilibrium_speed(nominal_params(corrected), v)
        d = effect.design(w)
        out[v] = {
            "speed": w,
            "lower": [abs(c) for c in d.lower],
            "upper": [abs(c) for c in d.upper],
            "decay_rate": effect.decay_rate(w),
        }
    return out


def _phase_errors(ctrls, design_of, truth, rows, cfg: SimToRealConfig) -> dict[str, dict[float, float]]:
    """Per design and voltage, the angle of G_true / G_design for the first harmonic [deg]
    (:func:`drill_env.agents.controllers.angle_feedforward.phase_error`, the truth without its effect): the
    feedforward's adaptation converges while it lies within +-90 deg."""
    from drill_env.agents.controllers.angle_feedforward import phase_error
    from drill_env.envs.task import nominal_params

    if "lqi_angle_ff" not in cfg.controllers:
        return {}
    truth_linear = nominal_params(truth)
    speed = {r["voltage"]: r["target_speed"] for r in rows if r["controller"] == "open_loop"}
    out: dict[str, dict[float, float]] = {}
    for d, (params, _) in design_of.items():
        lqi = ctrls[(d, "lqi_angle_ff")].lqi
        out[d] = {
            v: math.degrees(float(phase_error(nominal_params(params), truth_linear, speed[v], lqi)[0]))
            for v in cfg.voltages
        }
    return out


def _before_after(res: SimToRealResult) -> list[str]:
    import pandas as pd

    cfg = res.config
    df = res.to_pandas()
    lines = [
        "## Before and after, on the truth plant",
        "",
        f"Mean over seeds {', '.join(str(s) for s in cfg.seeds)}; suppression = 1 - amplitude / open-loop "
        "amplitude on the truth plant at the same voltage and seed; RMS speed error of the lower disk "
        "[rad/s] in the steady window. Each cell: nominal design → corrected design.",
        "",
        "| controller | metric | " + " | ".join(f"{v:g} V" for v in cfg.voltages) + " | worst |",
        "|---|---|" + "---|" * (len(cfg.voltages) + 1),
    ]
    ol = df[df.controller == "open_loop"].groupby("voltage")["amplitude"].mean()
    lines.append(
        "| open loop | amplitude [rad/s] | "
        + " | ".join(_fmt(ol.get(v, math.nan), 2) for v in cfg.voltages)
        + " | |"
    )
    verdicts = []
    for c in cfg.controllers:
        for metric, worst in (("suppression", "min"), ("rms_error", "max")):
            cells = []
            agg = {}
            for d in DESIGNS:
                sub = df[(df.controller == c) & (df.design == d)]
                agg[d] = (sub.groupby("voltage")[metric].mean(), getattr(sub[metric], worst)())
            for v in cfg.voltages:
                cells.append(
                    f"{_fmt(agg['nominal'][0].get(v, math.nan))} → {_fmt(agg['corrected'][0].get(v, math.nan))}"
                )
            cells.append(f"{_fmt(agg['nominal'][1])} → {_fmt(agg['corrected'][1])}")
            label = "suppression" if metric == "suppression" else "RMS error [rad/s]"
            lines.append(f"| `{c}` | {label} | " + " | ".join(cells) + " |")
            if metric == "suppression":
                verdicts.append((c, agg["nominal"][1], agg["corrected"][1]))
    lines += ["", "Worst-case suppression over the grid, nominal → corrected design:", ""]
    for c, a, b in verdicts:
        if not (math.isfinite(a) and math.isfinite(b)):
            word = "no cycle to suppress on this grid"
        elif b > a + 0.02:
            word = "the corrected model helps"
        elif b < a - 0.02:
            word = "the corrected model makes it worse"
        else:
            word = "no material change (within 0.02)"
        lines.append(f"- `{c}`: {_fmt(a)} → {_fmt(b)}: {word}.")
    named = res.discrepancy.get("effects", [])
    if ANGLE_LOCKED in named and {"lqi", "lqi_angle_ff"} <= set(cfg.controllers):
        w = df[df.design != "-"].groupby(["controller", "design"])["suppression"].min()
        r = df[df.design != "-"].groupby(["controller", "design"])["rms_error"].max()
        lines += [
            "",
            f"What knowing the effect changes: the discrepancy named `{ANGLE_LOCKED}`, a friction locked "
            "to the lower disk's angle, which the linearised design model cannot contain but whose "
            "identified torque is a known function of the measured angle. Before the data a user deploys "
            "`lqi` on the nominal model: worst-case suppression "
            f"{_fmt(w.get(('lqi', 'nominal'), math.nan))}, worst RMS speed error "
            f"{_fmt(r.get(('lqi', 'nominal'), math.nan))} rad/s on the truth plant. After it, the same "
            "`lqi` designed on the corrected model, with the identified friction fed forward: "
            f"{_fmt(w.get(('lqi', 'corrected'), math.nan))} and {_fmt(r.get(('lqi', 'corrected'), math.nan))} "
            "rad/s; `lqi_angle_ff`, which learns the friction's harmonics without a model of them, "
            f"{_fmt(w.get(('lqi_angle_ff', 'nominal'), math.nan))} → "
            f"{_fmt(w.get(('lqi_angle_ff', 'corrected'), math.nan))}.",
        ]
    from drill_env.agents.registry import LEARNED

    for c in (c for c in cfg.controllers if c in LEARNED):
        w = df[(df.controller == c) & (df.design != "-")].groupby("design")["suppression"].min()
        lines += [
            "",
            f"`{c}` is not retrained on the corrected model: it is a residual policy on `lqi_angle_ff`, whose "
            "adaptation already rejects the friction before the data; on the corrected model its base is "
            "redesigned (the identified friction fed forward) and its trained correction kept. Measured: "
            f"worst-case suppression {_fmt(w.get('nominal', math.nan))} → {_fmt(w.get('corrected', math.nan))}; "
            "retraining would have to beat a base that leaves little to correct.",
        ]
    if res.phase_errors:
        lines += [
            "",
            "Why `lqi_angle_ff` is good before the data already: its adaptation needs only the phase of "
            "the closed loop's response at the rotation frequency within 90 deg of the truth's; the phase "
            "error of the first harmonic [deg], nominal → corrected design: "
            + ", ".join(
                f"{v:g} V {round(res.phase_errors['nominal'][v], 1) + 0.0:+.1f} → {round(res.phase_errors['corrected'][v], 1) + 0.0:+.1f}"
                for v in cfg.voltages
            )
            + ".",
        ]
    worst = df[df.design != "-"].groupby(["controller", "design"])["suppression"].min()
    deltas = [
        abs(worst.get((c, "corrected"), math.nan) - worst.get((c, "nominal"), math.nan))
        for c in cfg.controllers
    ]
    gain_change = max(
        (
            abs(res.gains["corrected"][k][n] / res.gains["nominal"][k][n] - 1.0)
            for k in res.gains["nominal"]
            for n in res.gains["nominal"][k]
            if res.gains["nominal"][k][n]
        ),
        default=0.0,
    )
    moved = float(np.nanmax(deltas)) if deltas and np.isfinite(deltas).any() else math.nan
    lines += [
        "",
        f"In short: retuning on the corrected model moves the gains by at most {gain_change:.1%}; the "
        f"corrected design moves the worst-case suppression by up to {_fmt(moved)}"
        + (
            ", through the effect the model names, fed forward; the recalibrated parameters alone "
            "change little (the linear designs are insensitive to parameter errors of this size)."
            if res.effect_feedforward
            else "."
        ),
        "",
        "The *after* rows are one public command: `drill-env benchmark --preset "
        f"{cfg.preset} --plant truth.yaml --design-params discrepancy/model.yaml --gains gains_corrected.yaml "
        f"--controllers {','.join(cfg.controllers)} --voltages {','.join(f'{v:g}' for v in cfg.voltages)} "
        f"--seeds {len(cfg.seeds)}` (with this example's episode settings; the plant is named by its "
        "file, the runs are the same); without `--design-params` and `--gains`, the *before* rows.",
    ]
    best = (
        df[df.design != "-"]
        .groupby(["controller", "design"])["suppression"]
        .min()
        .sort_values(ascending=False)
    )
    if len(best) and pd.notna(best.iloc[0]):
        (c, d), v = best.index[0], best.iloc[0]
        lines += ["", f"Best worst case: `{c}`, designed on the {d} model ({_fmt(v)})."]
    return lines


def parse_voltages(text: str) -> tuple[float, ...]:
    """Comma-separated voltages [V]; ValueError naming ``--voltages`` otherwise."""
    try:
        vs = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ValueError(f"--voltages: expected comma-separated numbers, got {text!r}") from None
    if not vs:
        raise ValueError(f"--voltages: expected at least one voltage, got {text!r}")
    return vs


CYCLES = ("limit_cycle", "stick_slip")  # the regimes with a cycle to suppress


def rig_voltages(model: Any, n: int) -> tuple[float, ...]:
    """``n`` voltages [V] of the before/after comparison on ``model`` (a lab's rig file), from
    its own analysis: in its regimes with a cycle (all its regimes if it has none)."""
    from drill_env.agents.evaluation.benchmark.grid import design_grid

    return design_grid(model, n, regimes=CYCLES)


def recording_voltages(model: Any, n: int) -> tuple[float, ...]:
    """``n`` constant voltages [V] to record on a rig whose model is ``model``: spread over
    every regime of its own analysis (where it turns, above its stick boundary)."""
    from drill_env.agents.evaluation.benchmark.grid import design_grid

    return design_grid(model, n)


def for_rig(cfg: SimToRealConfig, params_file: str | Path, *, voltages: bool = True) -> SimToRealConfig:
    """``cfg`` on the lab's rig model ``params_file`` (the nominal design, the discrepancy's
    reference, the built-in truth's base), with the recording voltages and (``voltages``) the
    compared voltages chosen from the rig's own analysis."""
    from drill_env.params import load_params

    model = load_params(params_file)
    synth = dataclasses.replace(
        cfg.synth, voltages=recording_voltages(model, max(3, len(cfg.synth.voltages)))
    )
    volts = rig_voltages(model, len(cfg.voltages)) if voltages else cfg.voltages
    return dataclasses.replace(
        cfg, synth=synth, params_file=str(params_file), voltages=volts, timeseries_voltage=volts[0]
    )


def quick_config(
    controllers: Sequence[str] = CONTROLLERS, voltages: Sequence[float] = (1.0,)
) -> SimToRealConfig:
    """A reduced example for a smoke run: short recordings, short episodes, one seed."""
    from drill_env.recordings.synth import SynthConfig

    return SimToRealConfig(
        synth=SynthConfig(
            preset="brake",
            voltages=(0.5, 1.0, 3.0),
            random_runs=1,
            duration_s=40.0,
            pre_roll_s=20.0,
            angle_noise_std=0.0,
        ),
        controllers=tuple(controllers),
        voltages=tuple(voltages),
        seeds=(0,),
        episode=EpisodeSettings(duration=20.0, window=8.0, warmup_time=20.0, warmup_jitter=1.0),
        timeseries_voltage=float(voltages[0]),
        design_points=3,
        tuning_grid=3,
    )
