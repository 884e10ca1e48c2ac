"""Measured-data format of the rig: a folder of runs plus ``dataset.json``.

A *dataset* is a folder holding

* ``dataset.json`` with at least ``{"preset": "brake" | "no_brake",
  "encoder_counts_per_rev": int}``; optional ``"sample_rate_hz"`` (checked against
  every run) and ``"description"``;
* one CSV file per run, header ``t,u,theta_u,theta_l``: time [s], amplifier input
  [V], encoder angles of the upper and lower disk [rad], sampled at any rate from
  100 Hz to 10 kHz. A run starts whenever its recording started (``t`` need not start
  at 0); its initial state is not given.

Sampling. The sample clock is uniform, or *jittered*: each time stamp within
:data:`MAX_JITTER` (10 %) of the period of its place on a uniform grid (a USB or PC-based
DAQ, a log written by a control loop). A jittered run is brought onto its uniform grid
(:func:`regularise_run`): sample ``k`` stands for the instant ``t0 + k T``, its angles
moved by the angle turned between the recorded and the grid instant (the local speed
times the time-stamp error) in whole encoder counts, so that they stay on the encoder
grid and the quantisation error keeps its nature; the voltage is the recorded sample's,
held over its step of the grid (a DAQ updates its output on its own clock and logs it with
the sample; a voltage from an external generator sampled by the DAQ shows each step up to
one sample late). The time-stamp error a run had is in
:attr:`MeasuredRun.time_jitter`. A *gap* (a step of a whole number of periods: samples
lost) is refused unless ``dataset.json`` says ``"split_at_gaps": true``; the parts are then
analysed as runs of their own, ``name@1``, ``name@2``... (every part at least
:data:`MIN_DURATION_S` long). A step that is neither (a glitch of the clock) is refused with
its line.

Conventions the workflow relies on: ``u`` is the voltage held from its sample to
the next (zero-order hold, as a DAQ records its analogue output); the angles are
unwrapped (cumulative) and share one zero, the position at which the string is
untwisted, so that ``theta_u - theta_l`` is the twist x1 and a position-dependent
friction has the same phase in every run (an encoder homed to its index pulse).

The loader rejects bad input with a message naming the file, the line and the
column; nothing is dropped or repaired silently.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.outputs import atomic_file, atomic_write_text, output_lock
from drill_env.params import RIG_VOLTAGE_LIMIT

__all__ = [
    "COLUMNS",
    "DatasetError",
    "MeasuredRun",
    "add_run",
    "MeasuredDataset",
    "load_dataset",
    "write_dataset",
    "RIG_VOLTAGE_LIMIT",
    "MIN_RATE_HZ",
    "MAX_RATE_HZ",
    "MIN_DURATION_S",
    "MAX_RUN_BYTES",
    "MAX_JITTER",
    "CONSTANT_VOLTAGE_TOL",
    "regularise_run",
]

COLUMNS = ("t", "u", "theta_u", "theta_l")
MIN_RATE_HZ = 100.0
MAX_RATE_HZ = 10_000.0
MIN_DURATION_S = 10.0  # shorter runs hold too few equation-error windows
MAX_SPEED_RAD_S = 100.0  # larger jumps between samples are a wrapped or glitched angle
_RATE_TOL = 1e-3  # relative tolerance on the sample period (float formatting of t)
_COUNTS_MAX = 1 << 26
_GRID_TOL = 1e-3  # [counts] how far an angle may sit from a whole encoder count (print rounding aside)
MAX_RUN_BYTES = 1 << 30  # a run file of more than 1 GiB (about 25 million samples) is refused unread
MAX_META_BYTES = 1 << 20
CONSTANT_VOLTAGE_TOL = 0.05  # [V] largest deviation from its median of a constant run's voltage
MAX_JITTER = 0.1  # largest time-stamp error of a jittered clock, in periods [-]
_GRID_FIT_MARGIN = 0.02  # [periods] the uniform grid is fitted to the time stamps, not known
_JITTERED_SHARE = 0.05  # share of odd steps above which a clock is jittered rather than glitched


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
    time_jitter: float = 0.0  # largest recorded time-stamp error brought onto the grid [periods]

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
        """Every sample within :data:`CONSTANT_VOLTAGE_TOL` of the run's median voltage: a
        constant input recorded through a noisy ADC (up to about 10 mV rms) is still constant."""
        return bool(np.max(np.abs(self.u - np.median(self.u))) <= CONSTANT_VOLTAGE_TOL)

    @property
    def voltage(self) -> float:
        """The constant voltage of a constant-voltage run (the median of its samples), else nan."""
        return float(np.median(self.u)) if self.is_constant_voltage else float("nan")

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


def _num(x: Any) -> str:
    """A number as the user wrote it, never ``np.float64(...)``."""
    return repr(float(x))


def _file_problem(path: Path, what: str, max_bytes: int) -> str | None:
    """Why ``path`` cannot be read as a ``what`` (None: a regular file of sane size).

    Checked before opening: a FIFO would block the reader and a sparse file of many GB
    would be read whole.
    """
    try:
        st = path.stat()
    except FileNotFoundError:
        if path.is_symlink():
            return f"a dangling link (its target {os.readlink(path)} does not exist); expected a {what}"
        return f"missing; expected a {what}"
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc}); expected a {what}"
    if stat.S_ISDIR(st.st_mode):
        return f"a folder, not a file; expected a {what}"
    if not stat.S_ISREG(st.st_mode):
        return f"not a regular file (a FIFO, socket or device); expected a {what}"
    if st.st_size > max_bytes:
        return f"{st.st_size} bytes, more than the {max_bytes} bytes allowed for a {what}"
    return None


def _read_text(path: Path, what: str, max_bytes: int) -> bytes:
    """The bytes of a UTF-8 text file (a BOM is allowed), or :class:`DatasetError` naming it."""
    problem = _file_problem(path, what, max_bytes)
    if problem is not None:
        raise DatasetError(f"{path}: {problem}")
    try:
        with open(path, "rb") as f:
            raw = f.read(max_bytes + 1)
    except OSError as exc:
        raise DatasetError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if len(raw) > max_bytes:
        raise DatasetError(f"{path}: more than the {max_bytes} bytes allowed for a {what}")
    hint = " (a macOS metadata file: delete it)" if path.name.startswith("._") else ""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise DatasetError(f"{path}: UTF-16 text{hint}; save the {what} as UTF-8")
    nul = raw.find(b"\x00")
    if nul >= 0:
        at = raw.count(b"\n", 0, nul) + 1
        raise DatasetError(
            f"{path}: a binary file (a NUL byte at line {at}){hint}; expected a {what} in UTF-8 text"
        )
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        at = raw.count(b"\n", 0, exc.start) + 1
        raise DatasetError(
            f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at line {at}){hint}; expected a {what}"
        ) from None
    return raw[3:] if raw.startswith(b"\xef\xbb\xbf") else raw


class _DuplicateKey(Exception):
    """A JSON object with a key twice (json keeps the last value silently)."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


def _load_meta(folder: Path) -> dict[str, Any]:
    from drill_env.params import available_presets

    path = folder / "dataset.json"
    if not path.exists() and not path.is_symlink():
        raise DatasetError(
            f"{path}: missing; a dataset folder needs dataset.json with 'preset' and 'encoder_counts_per_rev'"
        )
    raw = _read_text(path, "dataset.json", MAX_META_BYTES)
    try:
        meta = json.loads(raw.decode("utf-8"), object_pairs_hook=_unique_keys)
    except _DuplicateKey as exc:
        key = exc.args[0]
        text = raw.decode("utf-8")
        found = [m.start() for m in re.finditer(re.escape(json.dumps(key)) + r"\s*:", text)]
        where = f" (line {text.count(chr(10), 0, found[1]) + 1})" if len(found) > 1 else ""
        raise DatasetError(
            f"{path}: the key {key!r} appears twice{where}; which value holds is never guessed: keep one"
        ) from None
    except json.JSONDecodeError as exc:
        raise DatasetError(
            f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}): {exc.msg}"
        ) from None
    except (ValueError, RecursionError) as exc:  # an integer of thousands of digits, deep nesting
        raise DatasetError(
            f"{path}: not valid JSON ({' '.join(str(exc).split()) or 'nested too deeply'})"
        ) from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{path}: expected a JSON object, got {type(meta).__name__}")
    for key in ("preset", "encoder_counts_per_rev"):
        if key not in meta:
            raise DatasetError(f"{path}: field '{key}' is missing")
    presets = available_presets()
    if not isinstance(meta["preset"], str) or meta["preset"] not in presets:
        raise DatasetError(f"{path}: field 'preset' = {meta['preset']!r:.80}; allowed: {presets}")
    counts = meta["encoder_counts_per_rev"]
    if isinstance(counts, bool) or not isinstance(counts, int) or not 1 <= counts <= _COUNTS_MAX:
        raise DatasetError(
            f"{path}: field 'encoder_counts_per_rev' = {counts!r:.80}; expected an integer in [1, {_COUNTS_MAX}]"
        )
    split = meta.get("split_at_gaps", False)
    if not isinstance(split, bool):
        raise DatasetError(f"{path}: field 'split_at_gaps' = {split!r:.80}; expected true or false")
    rate = meta.get("sample_rate_hz")
    if rate is not None:
        if (
            isinstance(rate, bool)
            or not isinstance(rate, (int, float))
            or not (MIN_RATE_HZ <= rate <= MAX_RATE_HZ)
        ):
            raise DatasetError(
                f"{path}: field 'sample_rate_hz' = {rate!r:.80}; expected a number in "
                f"[{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}]"
            )
    return meta


def _first(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def _lines_of_rows(raw: bytes) -> tuple[bytes, np.ndarray]:
    """The CSV without blank lines, and the file's line number of every remaining line.

    Blank lines are allowed anywhere; a message still names the line of the file. Line
    ends are LF or CRLF; a CR that ends no CRLF pair (CR-only line ends, or a stray CR
    inside a line) is refused by :func:`_refuse_cr_and_quotes`, as is a quoted field.
    """
    body = raw[:-1] if raw.endswith(b"\n") else raw
    if b"\r" not in raw and re.search(rb"(?:^|\n)[ \t\f\v]*(?:\n|$)", body) is None:
        # the usual file: no blank line, LF line ends; not split into a list of lines
        return raw, np.arange(1, body.count(b"\n") + 2)
    if b"\r" in raw:
        raw = raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    lines = raw.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    keep = [i for i, ln in enumerate(lines) if ln.strip()]
    if len(keep) == len(lines):
        return raw, np.arange(1, len(lines) + 1)
    return b"\n".join(lines[i] for i in keep) + b"\n", np.asarray(keep, dtype=np.int64) + 1


def _refuse_cr_and_quotes(raw: bytes, name: str) -> None:
    """Refuse what a CSV reader would read its own way: a CR that is not part of a CRLF line
    end (CR-only line ends were the line end of classic Mac OS; readers differ on them) and a
    quoted field (``"0.5"``: a number written as text, which a parser would unquote
    silently), naming the line of the file."""
    for pattern, why in (
        (rb"\r(?!\n)", "a CR that ends no CR LF pair (CR-only line ends?); line ends are LF or CR LF"),
        (rb'"', "a quoted field; numbers are written unquoted"),
    ):
        m = re.search(pattern, raw)
        if m is not None:
            lineno = raw.count(b"\n", 0, m.start()) + 1
            if why.startswith("a CR"):
                lineno = raw.count(b"\r", 0, m.start()) + 1 if b"\n" not in raw[: m.start()] else lineno
            col = m.start() - (raw.rfind(b"\n", 0, m.start()) + 1) + 1
            raise DatasetError(f"{name}: line {lineno}, column {col}: {why}")


def _print_quantum(raw: bytes, col: int, tmax: float) -> float:
    """The rounding step of the printed numbers of column ``col`` near ``tmax`` [same unit].

    A writer prints a fixed number of decimals (``%.6f``) or of significant digits
    (``%.12g``, trailing zeros dropped); the most decimals and the most significant digits
    seen bound the rounding of every value: one unit in the last printed place. ``col``
    is the column's position.
    """
    import pandas as pd

    df = pd.read_csv(io.BytesIO(raw), usecols=[col], dtype=str, na_filter=False, skipinitialspace=True)
    text = df.iloc[:, 0].astype(str)
    parts = text.str.strip().str.extract(r"^[-+]?(\d*)(?:\.(\d*))?(?:[eE]([-+]?\d+))?$")
    whole = parts[0].fillna("")
    frac = parts[1].fillna("")
    exp = pd.to_numeric(parts[2].fillna("0"), errors="coerce").fillna(0.0)
    decimals = float((frac.str.len() - exp).max())
    digits = float((whole + frac).str.lstrip("0").str.len().max())
    if not (math.isfinite(decimals) and math.isfinite(digits)):
        return math.inf
    mag = math.floor(math.log10(tmax)) if tmax > 0 else 0
    try:
        return max(10.0 ** (-decimals), 10.0 ** (mag + 1 - max(digits, 1.0)))
    except OverflowError:
        return math.inf


def _clock(name: str, t: np.ndarray, d: np.ndarray, period: float, tol: float, uneven, line, split_at_gaps):
    """The segments ``[(start, stop)]`` of a clock that is not uniform to print resolution,
    and its largest time-stamp error [periods]; or :class:`DatasetError` naming the step.

    A few odd steps in a uniform record are glitches or gaps; many are a jittered clock. A
    step of ``n`` whole periods (within the jitter) is a gap of ``n - 1`` lost samples."""
    jittered = float(np.mean(uneven)) >= _JITTERED_SHARE
    bound = 2.0 * MAX_JITTER if jittered else 0.0  # two neighbouring errors in one step
    n_periods = np.round(d / period)
    off = np.abs(d - n_periods * period)
    gap = (n_periods >= 2) & (off <= bound * period + tol)
    glitch = (np.abs(d - period) > bound * period + tol) & ~gap
    what = (
        f"a jittered clock is accepted when every time stamp is within {MAX_JITTER:.0%} of the period "
        "of a uniform grid"
    )
    if glitch.any():
        i = _first(glitch) + 1
        raise DatasetError(
            f"{name}: line {line(i)}, column 't': step {d[i - 1]:.6g} s (from {_num(t[i - 1])} s on line "
            f"{line(i - 1)}) differs from the sample period {period:.6g} s by {abs(d[i - 1] - period):.3g} s "
            f"({abs(d[i - 1] - period) / period:.1%} of it) and is not a whole number of periods: sampling "
            f"must be uniform ({what}); a glitch of the clock? Cut the run at line {line(i)} into two "
            "files, or export the time stamps of the sample clock"
        )
    if gap.any() and not split_at_gaps:
        i = _first(gap) + 1
        raise DatasetError(
            f"{name}: line {line(i)}, column 't': step {d[i - 1]:.6g} s (from {_num(t[i - 1])} s on line "
            f"{line(i - 1)}) is {int(n_periods[i - 1])} sample periods of {period:.6g} s: "
            f"{int(n_periods[i - 1]) - 1} sample(s) lost, a gap in the recording; sampling must be uniform "
            f'({what}). Set "split_at_gaps": true in dataset.json to analyse the parts as runs of their '
            f"own (each at least {MIN_DURATION_S:g} s), or cut the file at line {line(i)}"
        )
    cuts = [0] + [int(i) + 1 for i in np.flatnonzero(gap)] + [t.size]
    segments = list(zip(cuts[:-1], cuts[1:], strict=True))
    worst = 0.0
    for a, b in segments:
        err = _grid_error(t[a:b])
        i = int(np.argmax(np.abs(err)))
        if abs(err[i]) > (MAX_JITTER + _GRID_FIT_MARGIN) * period + tol:
            raise DatasetError(
                f"{name}: line {line(a + i)}, column 't': time stamp {_num(t[a + i])} s is "
                f"{abs(err[i]):.3g} s ({abs(err[i]) / period:.1%} of the period {period:.6g} s) off the "
                f"uniform grid of its run; {what} (at most {MAX_JITTER * period:.3g} s): is the sample "
                "clock's rate drifting? Export the time stamps of the sample clock, or cut the run there"
            )
        worst = max(worst, float(np.max(np.abs(err))) / period)
    return segments, worst


def _grid_error(t: np.ndarray) -> np.ndarray:
    """Each time stamp's distance from the least-squares uniform grid through them [s] (the
    grid's rate is the clock's own, whatever the nominal rate)."""
    k = np.arange(t.size, dtype=float)
    slope, icpt = np.polyfit(k, t - t[0], 1)
    return t - t[0] - (icpt + slope * k)


def regularise_run(run: MeasuredRun, counts_per_rev: int) -> MeasuredRun:
    """``run`` on its uniform grid ``t[0] + k T`` (see the module docstring, *Sampling*).

    Each angle moves by ``-e_k w_k`` rounded to whole encoder counts, ``e_k`` the time
    stamp's error from the least-squares uniform grid and ``w_k`` the disk's speed over the
    neighbouring samples (about 10 ms either side, at the recorded instants); the angles stay
    on the encoder grid. A run already on its grid comes back unchanged."""
    t = np.asarray(run.t, dtype=float)
    if t.size < 3:
        return run
    err = _grid_error(t)
    grid = t - err
    T = float((grid[-1] - grid[0]) / (t.size - 1))
    k = np.arange(t.size)
    if not np.any(np.abs(err) > 1e-9 * T):
        return run
    step = 2.0 * math.pi / counts_per_rev
    m = max(1, int(round(0.01 / T)))
    out = {}
    for col in ("theta_u", "theta_l"):
        th = np.asarray(getattr(run, col), dtype=float)
        lo = np.clip(k - m, 0, t.size - 1)
        hi = np.clip(k + m, 0, t.size - 1)
        speed = (th[hi] - th[lo]) / (t[hi] - t[lo])
        out[col] = th + step * np.round(-err * speed / step)
    return MeasuredRun(
        name=run.name,
        t=grid,
        u=run.u,
        theta_u=out["theta_u"],
        theta_l=out["theta_l"],
        path=run.path,
        time_jitter=float(np.max(np.abs(err)) / T),
    )


def _load_csv(
    path: Path, expected_rate: float | None, counts_per_rev: int, split_at_gaps: bool = False
) -> list[MeasuredRun]:
    import pandas as pd

    raw = _read_text(path, "run file (CSV)", MAX_RUN_BYTES)
    name = path.name
    _refuse_cr_and_quotes(raw, name)
    raw, line_no = _lines_of_rows(raw)
    if line_no.size == 0:
        raise DatasetError(f"{name}: empty file; expected header {','.join(COLUMNS)}")

    def line(row: int) -> int:  # the file's line of data row ``row`` (0-based)
        return int(line_no[min(row + 1, line_no.size - 1)])

    try:
        df = pd.read_csv(io.BytesIO(raw), na_filter=False, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise DatasetError(f"{name}: empty file; expected header {','.join(COLUMNS)}") from None
    except (pd.errors.ParserError, ValueError, OverflowError) as exc:
        raise DatasetError(f"{name}: malformed CSV: {' '.join(str(exc).split())}") from None
    cols = [str(c).strip() for c in df.columns]
    header = f"line {int(line_no[0])} (header)"
    missing = [c for c in COLUMNS if c not in cols]
    if missing:
        raise DatasetError(
            f"{name}: {header}: missing column(s) {missing}; the header must be "
            f"{','.join(COLUMNS)} (found {','.join(cols)[:200]})"
        )
    extra = [c for c in cols if c not in COLUMNS]
    if extra:
        raise DatasetError(
            f"{name}: {header}: unexpected column(s) {extra[:10]}; the header must be {','.join(COLUMNS)}"
        )
    if len(set(cols)) != len(cols):
        raise DatasetError(f"{name}: {header}: a column appears twice ({','.join(cols)})")
    df.columns = cols
    if len(df) < 2:
        raise DatasetError(f"{name}: {len(df)} data row(s); a run needs many samples")
    data: dict[str, np.ndarray] = {}
    for col in COLUMNS:
        s = df[col]
        if not (pd.api.types.is_numeric_dtype(s.dtype) and not pd.api.types.is_bool_dtype(s.dtype)):
            num = pd.to_numeric(s.astype(str).str.strip(), errors="coerce")
            bad = (
                num.isna().to_numpy()
                & ~s.astype(str).str.strip().str.lower().isin(["nan", "+nan", "-nan"]).to_numpy()
            )
            if bad.any():
                i = _first(bad)
                raise DatasetError(
                    f"{name}: line {line(i)}, column '{col}': {str(s.iloc[i])[:40]!r} is not a number"
                )
            arr = num.to_numpy(dtype=float)
        else:
            arr = s.to_numpy(dtype=float)
        nonfinite = ~np.isfinite(arr)
        if nonfinite.any():
            i = _first(nonfinite)
            raise DatasetError(
                f"{name}: line {line(i)}, column '{col}': {str(df[col].iloc[i])[:40]!r} is not finite "
                "(NaN/inf are not allowed)"
            )
        data[col] = arr
    t = data["t"]
    d = np.diff(t)
    nonincreasing = d <= 0
    if nonincreasing.any():
        i = _first(nonincreasing) + 1
        raise DatasetError(
            f"{name}: line {line(i)}, column 't': time {_num(t[i])} s does not increase "
            f"(previous {_num(t[i - 1])} s on line {line(i - 1)}); time must be strictly increasing"
        )
    # the sample period: the median step, so that a gap is found where it is
    period = float(np.median(d))
    tmax = float(np.max(np.abs(t)))
    tol = max(_RATE_TOL * period, 8.0 * float(np.spacing(tmax)))
    uneven = np.abs(d - period) > tol
    if uneven.any():
        # Time stamps are printed to a fixed number of digits: an epoch time at 10 kHz, or
        # 2048 Hz written with 6 decimals, steps by +-1 unit of the last digit.
        # (Digits that cannot resolve a tenth of the period do not widen the tolerance: the
        # steps then show the coarse print themselves, and the first odd one is named.)
        quantum = _print_quantum(raw, cols.index("t"), tmax)
        print_tol = 2.02 * quantum + 8.0 * float(np.spacing(tmax))
        if print_tol <= 0.1 * period:
            tol = max(tol, print_tol)
        uneven = np.abs(d - period) > tol
    segments = [(0, t.size)]
    jitter = 0.0
    if uneven.any():
        segments, jitter = _clock(name, t, d, period, tol, uneven, line, split_at_gaps)
    dt = (t[-1] - t[0]) / (t.size - 1) if len(segments) == 1 else period
    rate = 1.0 / dt
    if not (MIN_RATE_HZ * (1 - _RATE_TOL) <= rate <= MAX_RATE_HZ * (1 + _RATE_TOL)):
        raise DatasetError(
            f"{name}: column 't': sample rate {rate:.6g} Hz is outside the allowed range "
            f"[{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}] Hz"
        )
    if expected_rate is not None and abs(rate - expected_rate) > _RATE_TOL * expected_rate:
        raise DatasetError(
            f"{name}: column 't': sample rate {rate:.6g} Hz differs from dataset.json "
            f"'sample_rate_hz' = {expected_rate:g} Hz"
        )
    if (
        len(segments) == 1 and t[-1] - t[0] < MIN_DURATION_S - 1e-3 * dt
    ):  # a run of exactly 10 s, its clock rounded, is one
        raise DatasetError(
            f"{name}: column 't': the run lasts {t[-1] - t[0]:.4g} s; at least {MIN_DURATION_S:g} s are needed"
        )
    u = data["u"]
    out = np.abs(u) > RIG_VOLTAGE_LIMIT + 1e-9
    if out.any():
        i = _first(out)
        raise DatasetError(
            f"{name}: line {line(i)}, column 'u': {_num(u[i])} V is outside the rig's range "
            f"[{-RIG_VOLTAGE_LIMIT:g}, {RIG_VOLTAGE_LIMIT:g}] V"
        )
    for col in ("theta_u", "theta_l"):
        jump = np.abs(np.diff(data[col])) > MAX_SPEED_RAD_S * np.maximum(d, dt)
        if jump.any():
            i = _first(jump) + 1
            raise DatasetError(
                f"{name}: line {line(i)}, column '{col}': the angle jumps by "
                f"{data[col][i] - data[col][i - 1]:.6g} rad in one sample (> {MAX_SPEED_RAD_S:g} rad/s); "
                "angles must be unwrapped (cumulative)"
            )
    for col in ("theta_u", "theta_l"):
        _check_encoder_grid(name, col, data[col], raw, cols.index(col), counts_per_rev, line)
    runs = []
    for j, (a, b) in enumerate(segments):
        part = f"{path.stem}@{j + 1}" if len(segments) > 1 else path.stem
        if t[b - 1] - t[a] < MIN_DURATION_S - 1e-3 * dt:  # as for a whole run: clock rounding
            raise DatasetError(
                f"{name}: lines {line(a)}-{line(b - 1)}, column 't': the part between gaps lasts "
                f"{t[b - 1] - t[a]:.4g} s; at least {MIN_DURATION_S:g} s are needed (split_at_gaps makes "
                "each part a run of its own); cut the short part out of the file"
            )
        run = MeasuredRun(
            name=part,
            t=t[a:b],
            u=u[a:b],
            theta_u=data["theta_u"][a:b],
            theta_l=data["theta_l"][a:b],
            path=path,
        )
        runs.append(regularise_run(run, counts_per_rev) if jitter > 0.0 else run)
    return runs


def _check_encoder_grid(
    name: str, col: str, theta: np.ndarray, raw: bytes, position: int, counts: int, line
) -> None:
    """Encoder angles are whole counts, ``k 2 pi / counts``: a wrong count does not fit them."""
    step = 2.0 * math.pi / counts
    k = theta / step
    off = np.abs(k - np.round(k))
    amax = float(np.max(np.abs(theta)))
    tol = _GRID_TOL + 8.0 * float(np.spacing(amax)) / step
    if not (off > tol).any():
        return
    quantum = _print_quantum(raw, position, amax)  # the angles' printed digits
    tol = max(tol, (0.51 * quantum + 8.0 * float(np.spacing(amax))) / step)
    if tol > 0.1:
        return  # printed too coarsely to tell whole counts: nothing to check against
    bad = off > tol
    if bad.any():
        i = _first(bad)
        raise DatasetError(
            f"{name}: line {line(i)}, column '{col}': {_num(theta[i])} rad is {_num(k[i])} encoder counts, "
            f"not a whole number; dataset.json 'encoder_counts_per_rev' = {counts} (one count = "
            f"{step:.6g} rad) does not fit the angles: is it the encoder's count after quadrature decoding?"
        )


def _check_common_divisor(runs: tuple[MeasuredRun, ...], counts: int, path: Path) -> None:
    """Angles that are all even (or all multiples of g) counts: the count per revolution is g times too large."""
    step = 2.0 * math.pi / counts
    ks = []
    for r in runs:
        for th in (r.theta_u, r.theta_l):
            k = np.round(th / step)
            if np.max(np.abs(k), initial=0.0) >= 2.0**62:
                return
            ks.append(np.abs(k).astype(np.int64))
    k_all = np.unique(np.concatenate(ks))
    if k_all.size < 50:
        return  # too few distinct readings to judge
    g = int(np.gcd.reduce(k_all))
    if g >= 2:
        raise DatasetError(
            f"{path}: field 'encoder_counts_per_rev' = {counts}: every angle of every run is a multiple of "
            f"{g} counts, so the encoder has {counts // g if counts % g == 0 else counts / g:g} counts per "
            "revolution, not "
            f"{counts}; correct the field"
        )


def load_dataset(folder: str | Path) -> MeasuredDataset:
    """Load and validate a dataset folder (see the module docstring for the format)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder; a dataset is a folder of CSV runs plus dataset.json")
    meta = _load_meta(folder)
    try:
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".csv")
    except OSError as exc:
        raise DatasetError(f"{folder}: cannot list the folder ({exc.strerror or exc})") from None
    if not files:
        raise DatasetError(f"{folder}: no run files (*.csv)")
    stems: dict[str, Path] = {}
    for f in files:
        if f.stem in stems:
            raise DatasetError(f"{folder}: two run files named {f.stem!r} ({stems[f.stem].name}, {f.name})")
        stems[f.stem] = f
    rate = meta.get("sample_rate_hz")
    counts = int(meta["encoder_counts_per_rev"])
    split = bool(meta.get("split_at_gaps", False))
    loaded = [
        (f, r) for f in files for r in _load_csv(f, float(rate) if rate is not None else None, counts, split)
    ]
    runs = tuple(r for _, r in loaded)
    seen: dict[str, Path] = {}  # each run's file
    for f, r in loaded:
        if r.name in seen:  # a part of a run split at its gaps named like another file
            raise DatasetError(
                f"{folder}: two runs named {r.name!r} ({seen[r.name].name}, {f.name}): the parts "
                "of a run split at its gaps are named <file>@1, <file>@2, ...; rename the other file"
            )
        seen[r.name] = f
    _check_common_divisor(runs, counts, folder / "dataset.json")
    return MeasuredDataset(
        preset=str(meta["preset"]),
        encoder_counts_per_rev=counts,
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
    split_at_gaps: bool = False,
) -> Path:
    """Write runs and ``dataset.json`` in the measured-data format (the folder held meanwhile,
    see :func:`drill_env.outputs.output_lock`). ``split_at_gaps``: a run whose clock has gaps
    (samples lost) is analysed as the parts between them (``"split_at_gaps": true``)."""
    folder = Path(folder)
    with output_lock(folder, "dataset"):
        return _write_dataset(folder, runs, preset, encoder_counts_per_rev, description, split_at_gaps)


def _write_dataset(
    folder: Path,
    runs: list[MeasuredRun],
    preset: str,
    encoder_counts_per_rev: int,
    description: str,
    split_at_gaps: bool = False,
) -> Path:
    import pandas as pd

    rates = sorted({round(1.0 / r.dt, 6) for r in runs})
    meta: dict[str, Any] = {"preset": preset, "encoder_counts_per_rev": int(encoder_counts_per_rev)}
    if len(rates) == 1:
        meta["sample_rate_hz"] = rates[0]
    if description:
        meta["description"] = description
    if split_at_gaps:
        meta["split_at_gaps"] = True
    # dataset.json is what makes the folder a dataset: removed first and written last, so that
    # a write interrupted (Ctrl-C, a full disk) leaves a folder that never loads as complete
    (folder / "dataset.json").unlink(missing_ok=True)
    for r in runs:
        df = pd.DataFrame({"t": r.t, "u": r.u, "theta_u": r.theta_u, "theta_l": r.theta_l})
        with atomic_file(folder / f"{r.name}.csv", "w", newline="") as f:
            df.to_csv(f, index=False, float_format="%.12g")
    atomic_write_text(folder / "dataset.json", json.dumps(meta, indent=2) + "\n")
    return folder


def add_run(folder: str | Path, run: MeasuredRun, *, split_at_gaps: bool = False) -> Path:
    """Add one run to the dataset in ``folder`` without rewriting its other runs (their files
    stay byte for byte); ``dataset.json`` keeps its fields, gains ``"split_at_gaps": true`` when
    asked, and is written last. The dataset must load before (:func:`load_dataset` refuses
    what does not) and the run's name must be new there."""
    import pandas as pd

    folder = Path(folder)
    with output_lock(folder, "dataset"):
        meta = json.loads((folder / "dataset.json").read_text(encoding="utf-8"))
        if (folder / f"{run.name}.csv").exists():
            raise DatasetError(f"{folder}: already holds a run named {run.name!r}")
        if split_at_gaps:
            meta["split_at_gaps"] = True
        if "sample_rate_hz" in meta and abs(float(meta["sample_rate_hz"]) * run.dt - 1.0) > 1e-6:
            del meta["sample_rate_hz"]  # runs at more than one rate: each CSV's own clock
        df = pd.DataFrame({"t": run.t, "u": run.u, "theta_u": run.theta_u, "theta_l": run.theta_l})
        with atomic_file(folder / f"{run.name}.csv", "w", newline="") as f:
            df.to_csv(f, index=False, float_format="%.12g")
        atomic_write_text(folder / "dataset.json", json.dumps(meta, indent=2) + "\n")
    return folder
