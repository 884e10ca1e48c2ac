"""Measured-data format of the rig: a folder of runs plus ``dataset.json``.

A *dataset* is a folder holding

* ``dataset.json`` with at least ``{"preset": "brake" | "no_brake",
  "encoder_counts_per_rev": int}``; optional ``"sample_rate_hz"`` (checked against
  every run) and ``"description"``;
* one CSV file per run, header ``t,u,theta_u,theta_l``: time [s], amplifier input
  [V], encoder angles of the upper and lower disk [rad], uniformly sampled at any
  rate from 100 Hz to 10 kHz. A run starts whenever its recording started (``t``
  need not start at 0); its initial state is not given.

Conventions the workflow relies on: ``u`` is the voltage held from its sample to
the next (zero-order hold, as a DAQ records its analogue output); the angles are
unwrapped (cumulative) and share one zero, the position at which the string is
untwisted, so that ``theta_u - theta_l`` is the twist x1 and a position-dependent
friction has the same phase in every run (an encoder homed to its index pulse).

The loader rejects bad input with a message naming the file, the line and the
column; nothing is dropped or repaired silently.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.outputs import atomic_file, atomic_write_text, output_lock

__all__ = [
    "COLUMNS",
    "DatasetError",
    "MeasuredRun",
    "MeasuredDataset",
    "load_dataset",
    "write_dataset",
    "RIG_VOLTAGE_LIMIT",
    "MIN_RATE_HZ",
    "MAX_RATE_HZ",
    "MIN_DURATION_S",
]

COLUMNS = ("t", "u", "theta_u", "theta_l")
RIG_VOLTAGE_LIMIT = 5.0  # [V] amplifier input range of the rig, Sec. 2.1 of the paper
MIN_RATE_HZ = 100.0
MAX_RATE_HZ = 10_000.0
MIN_DURATION_S = 10.0  # shorter runs hold too few equation-error windows
MAX_SPEED_RAD_S = 100.0  # larger jumps between samples are a wrapped or glitched angle
_RATE_TOL = 1e-3  # relative tolerance on the sample period (float formatting of t)
_COUNTS_MAX = 1 << 26


class DatasetError(ValueError):
    """A dataset file is missing, malformed or outside the rig's range."""


@dataclass(frozen=True)
class MeasuredRun:
    """One recording: uniformly sampled input and encoder angles."""

    name: str  # file stem
    t: np.ndarray  # [s] as recorded
    u: np.ndarray  # [V], zero-order hold from each sample to the next
    theta_u: np.ndarray  # [rad] upper-disk angle
    theta_l: np.ndarray  # [rad] lower-disk angle
    path: Path | None = None

    @property
    def dt(self) -> float:
        return float((self.t[-1] - self.t[0]) / (self.t.size - 1))

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def t_rel(self) -> np.ndarray:
        """Time since the start of the recording [s]."""
        return self.t - self.t[0]

    @property
    def is_constant_voltage(self) -> bool:
        return bool(np.ptp(self.u) <= 1e-6)

    @property
    def voltage(self) -> float:
        """The constant voltage of a constant-voltage run, else nan."""
        return float(self.u[0]) if self.is_constant_voltage else float("nan")

    @property
    def label(self) -> str:
        if self.is_constant_voltage:
            return f"{self.name} ({self.voltage:g} V)"
        return f"{self.name} (varying {self.u.min():.2g}-{self.u.max():.2g} V)"


@dataclass(frozen=True)
class MeasuredDataset:
    """A folder of runs of one rig configuration."""

    preset: str
    encoder_counts_per_rev: int
    runs: tuple[MeasuredRun, ...]
    path: Path | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def encoder_step(self) -> float:
        """Angle of one encoder count [rad]."""
        return 2.0 * math.pi / self.encoder_counts_per_rev

    @property
    def sample_rate_hz(self) -> float:
        return float(np.median([1.0 / r.dt for r in self.runs]))

    def run(self, name: str) -> MeasuredRun:
        for r in self.runs:
            if r.name == name:
                return r
        raise KeyError(f"no run named {name!r}; runs: {[r.name for r in self.runs]}")


# -- loading ------------------------------------------------------------------------------


def _load_meta(folder: Path) -> dict[str, Any]:
    from drill_env.params import available_presets

    path = folder / "dataset.json"
    if not path.is_file():
        raise DatasetError(
            f"{path}: missing; a dataset folder needs dataset.json with 'preset' and 'encoder_counts_per_rev'"
        )
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(
            f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}): {exc.msg}"
        ) from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{path}: expected a JSON object, got {type(meta).__name__}")
    for key in ("preset", "encoder_counts_per_rev"):
        if key not in meta:
            raise DatasetError(f"{path}: field '{key}' is missing")
    presets = available_presets()
    if meta["preset"] not in presets:
        raise DatasetError(f"{path}: field 'preset' = {meta['preset']!r}; allowed: {presets}")
    counts = meta["encoder_counts_per_rev"]
    if isinstance(counts, bool) or not isinstance(counts, int) or not 1 <= counts <= _COUNTS_MAX:
        raise DatasetError(
            f"{path}: field 'encoder_counts_per_rev' = {counts!r}; expected an integer in [1, {_COUNTS_MAX}]"
        )
    rate = meta.get("sample_rate_hz")
    if rate is not None:
        if (
            isinstance(rate, bool)
            or not isinstance(rate, (int, float))
            or not (MIN_RATE_HZ <= rate <= MAX_RATE_HZ)
        ):
            raise DatasetError(
                f"{path}: field 'sample_rate_hz' = {rate!r}; expected a number in "
                f"[{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}]"
            )
    return meta


def _first(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def _load_csv(path: Path, expected_rate: float | None) -> MeasuredRun:
    import pandas as pd

    try:
        df = pd.read_csv(path, na_filter=False, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise DatasetError(f"{path.name}: empty file; expected header {','.join(COLUMNS)}") from None
    except pd.errors.ParserError as exc:
        raise DatasetError(f"{path.name}: malformed CSV: {str(exc).strip()}") from None
    cols = [str(c).strip() for c in df.columns]
    missing = [c for c in COLUMNS if c not in cols]
    if missing:
        raise DatasetError(
            f"{path.name}: line 1 (header): missing column(s) {missing}; the header must be "
            f"{','.join(COLUMNS)} (found {','.join(cols)})"
        )
    extra = [c for c in cols if c not in COLUMNS]
    if extra:
        raise DatasetError(
            f"{path.name}: line 1 (header): unexpected column(s) {extra}; the header must be "
            f"{','.join(COLUMNS)}"
        )
    if len(set(cols)) != len(cols):
        raise DatasetError(f"{path.name}: line 1 (header): a column appears twice ({','.join(cols)})")
    df.columns = cols
    if len(df) < 2:
        raise DatasetError(f"{path.name}: {len(df)} data row(s); a run needs many samples")
    data: dict[str, np.ndarray] = {}
    for col in COLUMNS:
        s = df[col]
        if not (pd.api.types.is_numeric_dtype(s.dtype) and not pd.api.types.is_bool_dtype(s.dtype)):
            num = pd.to_numeric(s, errors="coerce")
            bad = (
                num.isna().to_numpy()
                & ~s.astype(str).str.strip().str.lower().isin(["nan", "+nan", "-nan"]).to_numpy()
            )
            if bad.any():
                i = _first(bad)
                raise DatasetError(
                    f"{path.name}: line {i + 2}, column '{col}': {s.iloc[i]!r} is not a number"
                )
            arr = num.to_numpy(dtype=float)
        else:
            arr = s.to_numpy(dtype=float)
        nonfinite = ~np.isfinite(arr)
        if nonfinite.any():
            i = _first(nonfinite)
            raise DatasetError(
                f"{path.name}: line {i + 2}, column '{col}': {df[col].iloc[i]!r} is not finite "
                "(NaN/inf are not allowed)"
            )
        data[col] = arr
    t = data["t"]
    d = np.diff(t)
    nonincreasing = d <= 0
    if nonincreasing.any():
        i = _first(nonincreasing) + 1
        raise DatasetError(
            f"{path.name}: line {i + 2}, column 't': time {t[i]!r} s does not increase "
            f"(previous {t[i - 1]!r} s); time must be strictly increasing"
        )
    dt = (t[-1] - t[0]) / (t.size - 1)
    uneven = np.abs(d - dt) > _RATE_TOL * dt
    if uneven.any():
        i = _first(uneven) + 1
        raise DatasetError(
            f"{path.name}: line {i + 2}, column 't': step {d[i - 1]:.6g} s differs from the mean "
            f"sample period {dt:.6g} s by more than {_RATE_TOL:.0e} of it; sampling must be uniform"
        )
    rate = 1.0 / dt
    if not (MIN_RATE_HZ * (1 - _RATE_TOL) <= rate <= MAX_RATE_HZ * (1 + _RATE_TOL)):
        raise DatasetError(
            f"{path.name}: column 't': sample rate {rate:.6g} Hz is outside the allowed range "
            f"[{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}] Hz"
        )
    if expected_rate is not None and abs(rate - expected_rate) > _RATE_TOL * expected_rate:
        raise DatasetError(
            f"{path.name}: column 't': sample rate {rate:.6g} Hz differs from dataset.json "
            f"'sample_rate_hz' = {expected_rate:g} Hz"
        )
    if t[-1] - t[0] < MIN_DURATION_S:
        raise DatasetError(
            f"{path.name}: column 't': the run lasts {t[-1] - t[0]:.4g} s; at least {MIN_DURATION_S:g} s "
            "are needed"
        )
    u = data["u"]
    out = np.abs(u) > RIG_VOLTAGE_LIMIT + 1e-9
    if out.any():
        i = _first(out)
        raise DatasetError(
            f"{path.name}: line {i + 2}, column 'u': {u[i]!r} V is outside the rig's range "
            f"[{-RIG_VOLTAGE_LIMIT:g}, {RIG_VOLTAGE_LIMIT:g}] V"
        )
    for col in ("theta_u", "theta_l"):
        jump = np.abs(np.diff(data[col])) > MAX_SPEED_RAD_S * dt
        if jump.any():
            i = _first(jump) + 1
            raise DatasetError(
                f"{path.name}: line {i + 2}, column '{col}': the angle jumps by "
                f"{data[col][i] - data[col][i - 1]:.6g} rad in one sample (> {MAX_SPEED_RAD_S:g} rad/s); "
                "angles must be unwrapped (cumulative)"
            )
    return MeasuredRun(name=path.stem, t=t, u=u, theta_u=data["theta_u"], theta_l=data["theta_l"], path=path)


def load_dataset(folder: str | Path) -> MeasuredDataset:
    """Load and validate a dataset folder (see the module docstring for the format)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder; a dataset is a folder of CSV runs plus dataset.json")
    meta = _load_meta(folder)
    files = sorted(folder.glob("*.csv"))
    if not files:
        raise DatasetError(f"{folder}: no run files (*.csv)")
    rate = meta.get("sample_rate_hz")
    runs = tuple(_load_csv(f, float(rate) if rate is not None else None) for f in files)
    return MeasuredDataset(
        preset=str(meta["preset"]),
        encoder_counts_per_rev=int(meta["encoder_counts_per_rev"]),
        runs=runs,
        path=folder,
        meta=meta,
    )


# -- writing ------------------------------------------------------------------------------


def write_dataset(
    folder: str | Path,
    runs: list[MeasuredRun],
    *,
    preset: str,
    encoder_counts_per_rev: int,
    description: str = "",
) -> Path:
    """Write runs and ``dataset.json`` in the measured-data format (the folder held meanwhile,
    see :func:`drill_env.outputs.output_lock`)."""
    folder = Path(folder)
    with output_lock(folder, "dataset"):
        return _write_dataset(folder, runs, preset, encoder_counts_per_rev, description)


def _write_dataset(
    folder: Path, runs: list[MeasuredRun], preset: str, encoder_counts_per_rev: int, description: str
) -> Path:
    import pandas as pd

    rates = sorted({round(1.0 / r.dt, 6) for r in runs})
    meta: dict[str, Any] = {"preset": preset, "encoder_counts_per_rev": int(encoder_counts_per_rev)}
    if len(rates) == 1:
        meta["sample_rate_hz"] = rates[0]
    if description:
        meta["description"] = description
    atomic_write_text(folder / "dataset.json", json.dumps(meta, indent=2) + "\n")
    for r in runs:
        df = pd.DataFrame({"t": r.t, "u": r.u, "theta_u": r.theta_u, "theta_l": r.theta_l})
        with atomic_file(folder / f"{r.name}.csv", "w", newline="") as f:
            df.to_csv(f, index=False, float_format="%.12g")
    return folder
