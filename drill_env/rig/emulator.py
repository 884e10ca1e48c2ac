"""An emulated rig: the exact simulator paced to the wall clock behind the wire protocol.

``drill-env emulate-rig`` runs :class:`EmulatedRig` in a process of its own and serves it
on a UDP port (:func:`serve`), so that a control loop is tested end to end on loopback
exactly as it runs against hardware. The plant is the truth: a preset or rig YAML with its
effects, and a plant file's measurement chain where the wire can carry it (encoder
resolution, sample clock, transport delay, angle noise: all before the counts leave the
rig). Each sensor tick the rig integrates one sample period at the voltage applied then
(:func:`drill_env.envs._core.rig_step` with one sample per step: the environment's own
compiled step, sensor chain included), and reports the encoder counts of that instant and
the voltage applied from it on. A COMMAND is applied from the first tick after it arrives;
a rig that has had no COMMAND for the START's command timeout sets 0 V by itself (as an I/O
box's own watchdog should).

``time_scale`` runs the rig's clock faster than the wall clock (tests only: a real rig runs
at 1); it is announced in HELLO_REPLY, and a controller's period in wall-clock time is its
period divided by it.
"""

from __future__ import annotations

import math
import select
import signal
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numba as nb
import numpy as np

from drill_env import _layout as L
from drill_env._numba import JIT_ALLOC
from drill_env.envs import _core as C
from drill_env.rig.protocol import (
    MAX_SAMPLES_PER_READING,
    NO_COMMAND,
    Command,
    Hello,
    HelloReply,
    ProtocolError,
    Reading,
    RigInfo,
    Start,
    Stop,
    Stopped,
    decode,
    encode,
)
from drill_env.sensors import (
    C_ANGLE_NOISE,
    C_INV_RES,
    C_TS,
    S_QL,
    S_QU,
    sensor_noise,
    sensor_reset,
    sensor_sample,
)

__all__ = ["MAX_TIME_SCALE", "EmulatedRig", "LockstepRig", "emulated_plant", "serve"]

MAX_TIME_SCALE = 50.0  # beyond this the simulator cannot keep up with the clock on one core


@nb.njit(**JIT_ALLOC)
def _advance(p, y, modes, ep, ecfg, scfg, sst, rng, u, m, counts, truth):
    """Integrate ``m`` sensor periods at the voltage ``u`` [V] and run the rig's encoders (delay,
    angle noise, quantisation: :func:`drill_env.sensors.sensor_sample`) at each: the counts
    (m, 2) and the true state (m, 6: twist, upper and lower speed, upper and lower angle, lower
    disk stuck) at ticks tick+1 .. tick+m. Returns the kernel status."""
    ws = C.workspace(m)
    t_out = ws[0]
    ts = scfg[C_TS]
    tick0 = ep[C.EP_TICK]
    for k in range(m):
        t_out[k] = (tick0 + k + 1) * ts
    ybuf = np.empty((m, L.NY))
    mbuf = np.empty((m, 2), dtype=np.int64)
    ubuf = np.empty(m)
    status = C._integrate(p, y, modes, tick0 * ts, (tick0 + m) * ts, u, t_out, ybuf, mbuf, ubuf, ep, ecfg, ws)
    noise = ws[1]
    if scfg[C_ANGLE_NOISE] > 0.0:
        sensor_noise(scfg, rng, noise)
    inv_res = scfg[C_INV_RES]
    for k in range(m):
        thl = ybuf[k, L.THL]
        sensor_sample(scfg, sst, ybuf[k, L.X1] + thl, thl, noise, k)
        counts[k, 0] = round(sst[S_QU] * inv_res)
        counts[k, 1] = round(sst[S_QL] * inv_res)
        truth[k, 0] = ybuf[k, L.X1]
        truth[k, 1] = ybuf[k, L.X2]
        truth[k, 2] = ybuf[k, L.X3]
        truth[k, 3] = ybuf[k, L.X1] + thl
        truth[k, 4] = thl
        truth[k, 5] = 1.0 if mbuf[k, 1] == 0 else 0.0
    ep[C.EP_TICK] = tick0 + m
    return status


@dataclass
class EmulatedRig:
    """The plant ``params`` (effects included) seen through encoders ``sensors`` (their
    counts, clock, delay and angle noise), switched on at rest and 0 V."""

    params: Any  # RigParams
    sensors: Any  # SensorConfig
    voltage_limit: float = 5.0
    seed: int = 0
    tick: int = 0
    voltage: float = 0.0
    _state: dict[str, Any] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        from drill_env.envs.config import EnvSettings
        from drill_env.sensors import rng_state, state_size

        if self.sensors.counts_per_rev is None:
            raise ValueError("sensors.counts_per_rev: a rig has encoders; give its counts per revolution")
        if self.sensors.speed_noise_std > 0:
            raise ValueError(
                "sensors.speed_noise_std: noise on the speed estimate cannot be emulated behind the wire "
                "(the controller estimates the speed from the counts); allowed: 0 (give angle_noise_std)"
            )
        s = EnvSettings(
            params=self.params,
            control_dt=self.sensors.sample_period,
            sensors=self.sensors,
            start="rest",
            warmup_time=0.0,
            warmup_jitter=0.0,
            action_mode="voltage",
        )
        st = self._state
        st.update(
            p=s.params.as_array(),
            y=np.zeros(L.NY),
            modes=np.zeros(2, dtype=np.int64),
            ep=np.zeros(C.NEP),
            ecfg=s.ecfg.copy(),
            scfg=self.sensors.as_array(),
            sst=np.zeros(state_size(self.sensors.delay_samples)),
            rng=rng_state(np.random.default_rng(self.seed).integers(0, 2**64, size=4, dtype=np.uint64)),
        )
        st["ep"][C.EP_H] = 0.0
        # at rest, untwisted, at angle 0: the encoders read 0 and their delay line holds it
        sensor_reset(st["scfg"], st["sst"], 0.0, 0.0, 0.0, 0.0)
        self.counts = (0, 0)
        self.truth = np.zeros(6)
        self.truth[5] = 1.0

    def advance(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Integrate ``m`` sensor periods at :attr:`voltage`: the counts (m, 2) and true states
        (m, 6) at ticks ``tick + 1 .. tick + m`` (:func:`_advance`)."""
        st = self._state
        counts = np.empty((m, 2), dtype=np.int64)
        truth = np.empty((m, 6))
        status = _advance(
            st["p"], st["y"], st["modes"], st["ep"], st["ecfg"], st["scfg"], st["sst"], st["rng"],
            self.voltage, m, counts, truth,
        )  # fmt: skip
        if status != 0:
            from drill_env.kernel import STATUS_MESSAGES

            raise RuntimeError(f"emulated rig: the simulator stopped ({STATUS_MESSAGES[status]})")
        self.tick += m
        self.counts = (int(counts[-1, 0]), int(counts[-1, 1]))
        self.truth = truth[-1]
        return counts, truth

    def warm(self) -> None:
        """Load (or compile) the simulator's code by integrating a copy of the state for one
        sample period: the rig itself does not move. An emulator that serves before this has
        its first answers late by the seconds this takes."""
        st = {k: v.copy() for k, v in self._state.items()}
        _advance(
            st["p"], st["y"], st["modes"], st["ep"], st["ecfg"], st["scfg"], st["sst"], st["rng"],
            self.voltage, 1, np.empty((1, 2), dtype=np.int64), np.empty((1, 6)),
        )  # fmt: skip

    def apply(self, voltage: float) -> float:
        """Set the voltage applied from now on, within the amplifier's range; the voltage set."""
        self.voltage = min(max(float(voltage), -self.voltage_limit), self.voltage_limit)
        return self.voltage


class LockstepRig:
    """An :class:`EmulatedRig` in the caller's process as a :class:`~drill_env.rig.protocol.RigIO`,
    advanced by the loop itself: each :meth:`read` integrates the next block of samples at the
    voltage written last, so a command takes effect at the tick of the reading it answers, as
    in the environment's ``step`` (no wire, no wall clock, no latency). The loop's code runs as
    against a rig; what the benchmark's episode does is what it does.

    ``late_commands``: how many readings a command takes to arrive (0: in time; 1: each is
    applied only after the next reading was sent, a missed deadline every period, as a loop
    that runs a period behind its rig)."""

    def __init__(self, rig: EmulatedRig, fail_after: int | None = None, late_commands: int = 0):
        self.rig = rig
        self.n = 0
        self.seq = 0
        self.writes: list[float] = []
        self.stopped = False
        self.fail_after = fail_after  # readings before it stops answering (a rig that died)
        self.truth: list[tuple] = []
        self.late_commands = int(late_commands)
        self._pending: list[tuple[int, float]] = []  # commands written, not yet applied
        self._command_seq = 0
        self.last_command = NO_COMMAND

    def hello(self) -> RigInfo:
        r = self.rig
        return RigInfo(r.sensors.sample_rate_hz, int(r.sensors.counts_per_rev), r.voltage_limit, 1.0, r.tick)

    def start(self, samples_per_reading: int, command_timeout: float) -> None:
        self.n = int(samples_per_reading)

    def read(self, timeout: float) -> Reading | None:
        if self.fail_after is not None and self.seq >= self.fail_after:
            return None
        r = self.rig
        while len(self._pending) > self.late_commands:  # the commands that have arrived by now
            self.last_command, v = self._pending.pop(0)
            r.apply(v)
        first = r.tick + 1  # samples at ticks tick + 1 .. tick + n, as the environment's step
        u = r.voltage
        counts, truth = r.advance(self.n)
        self.truth.append((first, u, truth))
        self.seq += 1
        return Reading(
            self.seq - 1,
            first,
            counts[:, 0].copy(),
            counts[:, 1].copy(),
            np.full(self.n, u),
            self.last_command,
        )

    def write(self, voltage: float) -> int:
        self.writes.append(float(voltage))
        seq = self._command_seq
        self._command_seq += 1
        self._pending.append((seq, float(voltage)))
        if self.late_commands == 0:
            self.last_command, v = self._pending.pop()
            self.rig.apply(v)
        return seq

    def stop(self) -> bool:
        self.writes.append(0.0)
        self._pending.clear()
        self.rig.apply(0.0)
        self.stopped = True
        return True

    def close(self) -> None:
        pass


def emulated_plant(preset: str, plant: Path | None):
    """(RigParams, SensorConfig) of ``--preset`` (a preset or rig YAML) or of ``--plant`` (a plant
    file: parameters, effects and its measurement chain)."""
    from drill_env.params import resolve_params
    from drill_env.sensors import SensorConfig

    if plant is None:
        return resolve_params(preset), SensorConfig()
    from drill_env.plant_file import read_plant_file, without_measurement

    pf = without_measurement(read_plant_file(plant), "emulate-rig")
    return pf.params, SensorConfig(**pf.sensors)


class _TruthLog:
    """The emulator's true state at every tick (``--truth``): what no rig can record, for tests.
    ``u`` is the voltage applied over the period that ends at the row's instant."""

    COLUMNS = "t,u,x1,x2,x3,theta_u,theta_l,lower_stuck\n"

    def __init__(self, path: Path, rate: float):
        from drill_env.outputs import open_new

        self.f: IO[Any] = open_new(path)  # never through a link
        self.f.write(self.COLUMNS)
        self.ts = 1.0 / rate

    def add(self, first_tick: int, u: float, truth: np.ndarray) -> None:
        t = (first_tick + np.arange(truth.shape[0])) * self.ts
        rows = [
            f"{t[k]:.6f},{u:.9g},{x[0]:.10g},{x[1]:.10g},{x[2]:.10g},{x[3]:.10g},{x[4]:.10g},{int(x[5])}\n"
            for k, x in enumerate(truth)
        ]
        self.f.writelines(rows)

    def close(self) -> None:
        self.f.close()


class _Stream:
    """The samples of the rig not yet sent, each with the voltage applied from it on."""

    def __init__(self, rig: EmulatedRig, log: _TruthLog | None):
        self.rig, self.log = rig, log
        self.ticks: list[int] = [rig.tick]
        self.counts: list[tuple[int, int]] = [rig.counts]
        self.volts: list[float] = []  # one fewer: the last sample's voltage is the one applied now

    def advance_to(self, tick: int) -> None:
        """Integrate up to ``tick`` at the voltage applied now."""
        r = self.rig
        m = tick - r.tick
        if m <= 0:
            return
        u = r.voltage
        first = r.tick + 1
        counts, truth = r.advance(m)
        self.volts += [u] * m
        self.ticks += range(first, first + m)
        self.counts += [(int(c[0]), int(c[1])) for c in counts]
        if self.log is not None:
            self.log.add(first, u, truth)

    def take(self, first: int, last: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The samples of ticks ``first .. last`` (integrated up to ``last`` first); those
        before ``first`` are dropped."""
        self.advance_to(last)
        i0 = self.ticks.index(first) if first in self.ticks else 0
        i1 = self.ticks.index(last) + 1
        volts = self.volts + [self.rig.voltage]
        c = np.array(self.counts[i0:i1], dtype=np.int64).reshape(-1, 2)
        v = np.array(volts[i0:i1])
        del self.ticks[:i1], self.counts[:i1], self.volts[:i1]
        if not self.ticks:  # the last sample taken stays the head
            self.ticks, self.counts = [last], [self.rig.counts]
            # its voltage is not final yet: it was handed out as the one applied now
        return c[:, 0].copy(), c[:, 1].copy(), v

    def drop_to_now(self) -> None:
        """Forget the samples integrated so far (no client): keep only the present one."""
        self.ticks, self.counts, self.volts = [self.rig.tick], [self.rig.counts], []


def serve(
    rig: EmulatedRig,
    host: str = "127.0.0.1",
    port: int = 0,
    *,
    time_scale: float = 1.0,
    truth: Path | None = None,
    announce=print,
    max_ticks: int | None = None,
) -> None:
    """Serve ``rig`` on UDP ``host:port`` (0: any free port) until interrupted (Ctrl-C or
    SIGTERM), paced to the wall clock times ``time_scale``. ``announce`` receives one line
    with the address once the socket is bound.

    The rig is integrated lazily, in the pieces between the instants that matter (a COMMAND
    applied, a READING due), so that the emulator keeps up with the clock however fine the
    sensor clock: what a controller sees, and when, is as if it ran tick by tick."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    sock.bind((host, port))
    sock.setblocking(False)
    rate = rig.sensors.sample_rate_hz
    ticks_per_s = rate * time_scale  # rig ticks per wall-clock second
    log = _TruthLog(truth, rate) if truth is not None else None
    stream = _Stream(rig, log)
    client: Any = None
    per_reading = 0
    timeout_ticks = 0
    reading_seq = 0
    block_first = 0
    last_cmd = NO_COMMAND
    last_cmd_tick = 0
    timed_out = False

    def _term(signum, frame):  # noqa: ANN001
        raise KeyboardInterrupt

    rig.warm()  # before the address is announced: the first HELLO is answered at once
    old = signal.signal(signal.SIGTERM, _term)
    bound = sock.getsockname()
    announce(f"emulate-rig: listening on udp {bound[0]}:{bound[1]}")
    wall0 = time.monotonic()
    tick0 = rig.tick

    def now_tick() -> int:
        return tick0 + int((time.monotonic() - wall0) * ticks_per_s)

    try:
        while max_ticks is None or rig.tick < max_ticks:
            while True:
                try:
                    data, addr = sock.recvfrom(1 << 16)
                except (BlockingIOError, InterruptedError):
                    break
                except ConnectionResetError:
                    continue
                try:
                    msg = decode(data)
                except ProtocolError:
                    continue
                j = now_tick()
                if isinstance(msg, Hello):
                    info = RigInfo(rate, int(rig.sensors.counts_per_rev), rig.voltage_limit, time_scale, j)
                    sock.sendto(encode(HelloReply(msg.seq, info)), addr)
                elif isinstance(msg, Start):
                    if not 1 <= msg.samples_per_reading <= MAX_SAMPLES_PER_READING:
                        continue
                    stream.advance_to(j)
                    stream.drop_to_now()
                    client, per_reading = addr, int(msg.samples_per_reading)
                    timeout_ticks = max(1, int(math.ceil(msg.command_timeout * rate)))
                    reading_seq, last_cmd, last_cmd_tick, timed_out = 0, NO_COMMAND, j, False
                    block_first = j + 1
                elif isinstance(msg, Command) and addr == client:
                    stream.advance_to(j + 1)  # it arrived during tick j: applied from tick j + 1 on
                    rig.apply(msg.voltage)
                    last_cmd, last_cmd_tick, timed_out = msg.seq, j, False
                elif isinstance(msg, Stop):
                    stream.advance_to(j + 1)
                    rig.apply(0.0)
                    if addr == client:
                        client = None
                    sock.sendto(encode(Stopped(msg.seq, j + 1)), addr)
            j = now_tick()
            if client is None:
                stream.advance_to(j)
                stream.drop_to_now()
                next_due = j + max(1, int(rate * 0.01))
            else:
                if j - last_cmd_tick >= timeout_ticks and rig.voltage != 0.0:
                    stream.advance_to(j + 1)
                    rig.apply(0.0)
                    timed_out = True
                block_last = block_first + per_reading - 1
                if j >= block_last:
                    cu, cl, v = stream.take(block_first, block_last)
                    reading = Reading(reading_seq, block_first, cu, cl, v, last_cmd, timed_out)
                    try:
                        sock.sendto(encode(reading), client)
                    except OSError:
                        pass  # the controller is gone: the command timeout sets 0 V
                    reading_seq += 1
                    block_first = block_last + 1
                    continue
                next_due = min(block_last, last_cmd_tick + timeout_ticks)
            wait = (next_due - tick0) / ticks_per_s - (time.monotonic() - wall0)
            if wait > 0:
                select.select([sock], [], [], wait)
    except KeyboardInterrupt:
        pass
    finally:
        rig.apply(0.0)
        signal.signal(signal.SIGTERM, old)
        sock.close()
        if log is not None:
            log.close()
