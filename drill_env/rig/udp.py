"""A :class:`~drill_env.rig.protocol.RigIO` over UDP: the controller's side of the wire
protocol (:mod:`drill_env.rig.protocol`)."""

from __future__ import annotations

import math
import socket
import time

from drill_env.rig.protocol import (
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

__all__ = ["RigNotAnswering", "UdpRig", "parse_address"]


class RigNotAnswering(OSError):
    """No answer from the rig's address."""


def parse_address(text: str, name: str = "--rig") -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port); ValueError naming ``name`` otherwise."""
    host, sep, port = str(text).rpartition(":")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{name}: {text!r} is not HOST:PORT with a port in [1, 65535]")
    return host, int(port)


class UdpRig:
    """The rig at ``(host, port)``; every message sent is numbered (``seq``)."""

    def __init__(self, host: str, port: int):
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except socket.gaierror as exc:
            raise RigNotAnswering(f"--rig {host}:{port}: cannot resolve the host ({exc.strerror})") from None
        family, _, _, _, addr = infos[0]
        self.address = addr
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self._sock.connect(addr)
        self._seq = 0
        self.sent_commands = 0
        self.ignored = 0  # datagrams that were not messages of the protocol, or unexpected ones

    def _send(self, msg_type, *args) -> int:
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        msg = msg_type(seq, *args)
        try:
            self._sock.send(encode(msg))
        except OSError as exc:  # e.g. ECONNREFUSED from an earlier ICMP port-unreachable
            raise RigNotAnswering(f"--rig {self._where()}: {exc.strerror or exc}") from None
        return seq

    def _where(self) -> str:
        return f"{self.address[0]!s}:{self.address[1]!s}"

    def _recv(self, timeout: float):
        self._sock.settimeout(max(timeout, 1e-6))
        try:
            data = self._sock.recv(1 << 16)
        except TimeoutError:
            return None
        except ConnectionRefusedError:
            return None  # ICMP port unreachable: nobody listens there (counted as no answer)
        try:
            return decode(data)
        except ProtocolError:
            self.ignored += 1
            return False

    def hello(self, timeout: float = 1.0, tries: int = 3) -> RigInfo:
        for _ in range(tries):
            seq = self._send(Hello)
            deadline = time.monotonic() + timeout
            while (left := deadline - time.monotonic()) > 0:
                msg = self._recv(left)
                if msg is None:
                    break
                if isinstance(msg, HelloReply) and msg.seq == seq:
                    return msg.info
                self.ignored += msg is not False
        raise RigNotAnswering(
            f"--rig {self._where()}: no answer to HELLO within {timeout:g} s ({tries} tries); "
            "is the I/O box or `drill-env emulate-rig` running there?"
        )

    def start(self, samples_per_reading: int, command_timeout: float) -> None:
        self._send(Start, int(samples_per_reading), float(command_timeout))

    def read(self, timeout: float) -> Reading | None:
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            msg = self._recv(left)
            if msg is None:
                return None
            if isinstance(msg, Reading):
                return msg
            self.ignored += msg is not False
        return None

    def write(self, voltage: float) -> int:
        if not math.isfinite(voltage):
            raise ValueError(f"voltage: {voltage!r} is not finite")
        seq = self._send(Command, float(voltage))
        self.sent_commands += 1
        return seq

    def stop(self, timeout: float = 0.2) -> bool:
        """0 V and stop; True when the rig answered STOPPED within ``timeout`` s."""
        try:
            self.write(0.0)
            seq = self._send(Stop)
        except RigNotAnswering:
            return False
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            msg = self._recv(left)
            if msg is None:
                return False
            if isinstance(msg, Stopped) and msg.seq == seq:
                return True
        return False

    def close(self) -> None:
        self._sock.close()
