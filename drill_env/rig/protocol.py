"""The rig's I/O: the :class:`RigIO` protocol a control loop talks to, and its wire protocol.

A rig is whatever answers four calls (:class:`RigIO`): ``hello`` (what the rig is: its
sample clock, encoder resolution and amplifier range), ``start`` (stream readings), ``read``
(the encoder counts of the next block of sensor samples, with their tick stamps and the
voltage applied at each) and ``write`` (the voltage to apply from now on); ``stop`` sets
0 V. :class:`drill_env.rig.udp.UdpRig` speaks it over UDP to an I/O box (a real-time target,
a DAQ bridge, a microcontroller) or to ``drill-env emulate-rig``.

Wire protocol, version 1 (``docs/reference/rig_protocol.md`` has the tables). One message
per UDP datagram, every field little-endian, no padding. Every message starts with the
12-byte header :data:`HEADER` (``<4sBBHI``):

====== ===== ======= =====================================================================
offset bytes type    field
====== ===== ======= =====================================================================
0      4     char[4] magic ``b"DRIG"``
4      1     uint8   protocol version (1)
5      1     uint8   message type (:class:`MessageType`)
6      2     uint16  flags (0; reserved)
8      4     uint32  sequence number (below)
====== ===== ======= =====================================================================

Sequence numbers: the controller numbers its messages 0, 1, 2, ... (wrapping at 2^32); the
rig numbers its READINGs 0, 1, 2, ... from each START, so a lost reading shows as a gap; a
reply (HELLO_REPLY, STOPPED) carries the number of the request it answers.

The header is followed by the message's body (:data:`BODY`). The controller's messages are HELLO,
START, COMMAND and STOP; the rig answers HELLO with HELLO_REPLY, streams READING after
START, and answers STOP with STOPPED. A datagram of a wrong size, magic or version is
refused (:class:`ProtocolError`), never guessed at.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = [
    "BODY",
    "HEADER",
    "MAGIC",
    "MAX_SAMPLES_PER_READING",
    "SAMPLE",
    "VERSION",
    "Command",
    "Hello",
    "HelloReply",
    "MessageType",
    "ProtocolError",
    "Reading",
    "RigIO",
    "RigInfo",
    "Start",
    "Stop",
    "Stopped",
    "decode",
    "encode",
]

MAGIC = b"DRIG"
VERSION = 1
HEADER = struct.Struct("<4sBBHI")  # magic, version, type, flags, sequence number: 12 bytes
SAMPLE = struct.Struct("<qqf")  # per sensor sample of a READING: upper, lower counts, voltage [V]
# a READING holds at most this many samples (20 kB; above 73 samples a datagram is larger than
# an Ethernet frame and is carried in IP fragments, which loopback and a LAN deliver whole)
MAX_SAMPLES_PER_READING = 1000


class ProtocolError(ValueError):
    """A datagram that is not a message of this protocol."""


class MessageType(enum.IntEnum):
    """The message types (byte 5 of the header)."""

    HELLO = 1  # controller -> rig: who are you?
    HELLO_REPLY = 2  # rig -> controller: sample clock, encoder, amplifier, time scale, tick
    START = 3  # controller -> rig: stream READINGs of n samples each to me
    READING = 4  # rig -> controller: a block of sensor samples
    COMMAND = 5  # controller -> rig: apply this voltage from the next sample on
    STOP = 6  # controller -> rig: 0 V, stop streaming
    STOPPED = 7  # rig -> controller: done (0 V applied)


# Body of each message after the header (struct format; READING is followed by n SAMPLEs).
BODY: dict[MessageType, struct.Struct] = {
    MessageType.HELLO: struct.Struct("<"),
    # sample_rate_hz f64, counts_per_rev u32, voltage_limit f64 [V], time_scale f64, tick u64
    MessageType.HELLO_REPLY: struct.Struct("<dIddQ"),
    # samples per reading u16, command timeout [s of rig time] f64 (the rig sets 0 V when no
    # COMMAND arrived for that long)
    MessageType.START: struct.Struct("<Hd"),
    # tick of the first sample u64, number of samples u16, sequence number of the last COMMAND
    # applied u32 (0xFFFFFFFF: none yet), flags u16 (bit 0: the rig's own timeout set 0 V)
    MessageType.READING: struct.Struct("<QHIH"),
    MessageType.COMMAND: struct.Struct("<d"),  # voltage [V] f64
    MessageType.STOP: struct.Struct("<"),
    MessageType.STOPPED: struct.Struct("<Q"),  # tick at which 0 V was applied u64
}
NO_COMMAND = 0xFFFFFFFF
READING_TIMED_OUT = 1  # READING flag: the rig's command timeout set 0 V


@dataclass(frozen=True)
class RigInfo:
    """What a rig says about itself (HELLO_REPLY)."""

    sample_rate_hz: float  # [Hz] its sensor clock
    counts_per_rev: int  # encoder counts per revolution (both disks)
    voltage_limit: float  # [V] its amplifier range (+-)
    time_scale: float = 1.0  # rig seconds per wall-clock second (1 for hardware; emulator only)
    tick: int = 0  # its sample counter now

    @property
    def sample_period(self) -> float:
        return 1.0 / self.sample_rate_hz


@dataclass(frozen=True)
class Hello:
    seq: int = 0


@dataclass(frozen=True)
class HelloReply:
    seq: int
    info: RigInfo


@dataclass(frozen=True)
class Start:
    seq: int
    samples_per_reading: int
    command_timeout: float  # [s of rig time]


@dataclass(frozen=True)
class Reading:
    """A block of consecutive sensor samples, ticks ``first_tick .. first_tick + n - 1``."""

    seq: int
    first_tick: int
    counts_upper: np.ndarray  # int64 encoder counts
    counts_lower: np.ndarray  # int64
    voltage: np.ndarray  # [V] applied at each sample (float32 on the wire)
    last_command: int = NO_COMMAND  # sequence number of the last COMMAND applied
    timed_out: bool = False  # the rig's own command timeout has set 0 V

    @property
    def n(self) -> int:
        return int(self.counts_upper.size)


@dataclass(frozen=True)
class Command:
    seq: int
    voltage: float  # [V]


@dataclass(frozen=True)
class Stop:
    seq: int


@dataclass(frozen=True)
class Stopped:
    seq: int
    tick: int


Message = Hello | HelloReply | Start | Reading | Command | Stop | Stopped


def _header(kind: MessageType, seq: int) -> bytes:
    return HEADER.pack(MAGIC, VERSION, int(kind), 0, int(seq) & 0xFFFFFFFF)


def encode(msg: Message) -> bytes:
    """The datagram of a message."""
    if isinstance(msg, Hello):
        return _header(MessageType.HELLO, msg.seq)
    if isinstance(msg, HelloReply):
        i = msg.info
        body = BODY[MessageType.HELLO_REPLY].pack(
            i.sample_rate_hz, i.counts_per_rev, i.voltage_limit, i.time_scale, i.tick
        )
        return _header(MessageType.HELLO_REPLY, msg.seq) + body
    if isinstance(msg, Start):
        body = BODY[MessageType.START].pack(msg.samples_per_reading, msg.command_timeout)
        return _header(MessageType.START, msg.seq) + body
    if isinstance(msg, Reading):
        n = msg.n
        if not 1 <= n <= MAX_SAMPLES_PER_READING:
            raise ProtocolError(f"reading: {n} samples; allowed: 1 to {MAX_SAMPLES_PER_READING}")
        flags = READING_TIMED_OUT if msg.timed_out else 0
        head = BODY[MessageType.READING].pack(msg.first_tick, n, msg.last_command & 0xFFFFFFFF, flags)
        samples = np.empty(n, dtype=[("u", "<i8"), ("l", "<i8"), ("v", "<f4")])
        samples["u"], samples["l"], samples["v"] = msg.counts_upper, msg.counts_lower, msg.voltage
        return _header(MessageType.READING, msg.seq) + head + samples.tobytes()
    if isinstance(msg, Command):
        return _header(MessageType.COMMAND, msg.seq) + BODY[MessageType.COMMAND].pack(msg.voltage)
    if isinstance(msg, Stop):
        return _header(MessageType.STOP, msg.seq)
    if isinstance(msg, Stopped):
        return _header(MessageType.STOPPED, msg.seq) + BODY[MessageType.STOPPED].pack(msg.tick)
    raise TypeError(f"encode: not a message: {type(msg).__name__}")


def decode(data: bytes) -> Message:
    """The message of a datagram; :class:`ProtocolError` for anything else."""
    if len(data) < HEADER.size:
        raise ProtocolError(f"datagram of {len(data)} bytes is shorter than the {HEADER.size}-byte header")
    magic, version, kind, _flags, seq = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise ProtocolError(f"magic {magic!r} is not {MAGIC!r}")
    if version != VERSION:
        raise ProtocolError(f"protocol version {version}; this side speaks {VERSION}")
    try:
        mtype = MessageType(kind)
    except ValueError:
        raise ProtocolError(f"message type {kind} is unknown") from None
    body = BODY[mtype]
    rest = data[HEADER.size :]
    if mtype is MessageType.READING:
        if len(rest) < body.size:
            raise ProtocolError(f"READING of {len(data)} bytes is too short")
        first, n, last, flags = body.unpack_from(rest)
        if len(rest) != body.size + n * SAMPLE.size:
            raise ProtocolError(f"READING of {len(data)} bytes does not hold its {n} samples")
        s = np.frombuffer(rest, dtype=[("u", "<i8"), ("l", "<i8"), ("v", "<f4")], offset=body.size)
        return Reading(
            seq,
            first,
            s["u"].astype(np.int64),
            s["l"].astype(np.int64),
            s["v"].astype(np.float64),
            last,
            bool(flags & READING_TIMED_OUT),
        )
    if len(rest) != body.size:
        raise ProtocolError(f"{mtype.name} of {len(data)} bytes; expected {HEADER.size + body.size}")
    fields = body.unpack(rest)
    if mtype is MessageType.HELLO:
        return Hello(seq)
    if mtype is MessageType.HELLO_REPLY:
        rate, counts, vlim, scale, tick = fields
        return HelloReply(seq, RigInfo(rate, counts, vlim, scale, tick))
    if mtype is MessageType.START:
        return Start(seq, fields[0], fields[1])
    if mtype is MessageType.COMMAND:
        v = fields[0]
        if not math.isfinite(v):
            raise ProtocolError(f"COMMAND voltage {v!r} is not finite")
        return Command(seq, v)
    if mtype is MessageType.STOP:
        return Stop(seq)
    return Stopped(seq, fields[0])


@runtime_checkable
class RigIO(Protocol):
    """What a control loop needs of a rig (hardware behind an I/O box, or the emulator)."""

    def hello(self) -> RigInfo:
        """The rig's sample clock, encoder resolution, amplifier range and time scale."""
        ...

    def start(self, samples_per_reading: int, command_timeout: float) -> None:
        """Stream readings of ``samples_per_reading`` samples each; the rig sets 0 V by itself
        when no voltage was written for ``command_timeout`` seconds (of rig time)."""
        ...

    def read(self, timeout: float) -> Reading | None:
        """The next reading, or None when none arrived within ``timeout`` wall-clock seconds."""
        ...

    def write(self, voltage: float) -> int | None:
        """Apply ``voltage`` [V] from the next sensor sample on; the COMMAND's sequence number
        (which later READINGs report as applied), or None for a rig that does not number them."""
        ...

    def stop(self) -> bool:
        """0 V and stop streaming; True when the rig confirmed it (waits briefly for its answer)."""
        ...

    def close(self) -> None: ...
