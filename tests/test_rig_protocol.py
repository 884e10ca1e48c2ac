"""The rig's wire protocol, byte for byte against the documented layout (struct formats written
out here from docs/reference/rig_protocol.md, not taken from the module)."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from drill_env.rig import protocol as P


def test_header_is_twelve_bytes_little_endian():
    data = P.encode(P.Hello(seq=0x01020304))
    assert data == b"DRIG" + bytes([1, 1]) + b"\x00\x00" + bytes([4, 3, 2, 1])


def test_hello_reply_layout():
    info = P.RigInfo(1000.0, 2000, 5.0, 10.0, 123456789)
    data = P.encode(P.HelloReply(7, info))
    assert len(data) == 12 + 8 + 4 + 8 + 8 + 8
    assert data[12:] == struct.pack("<d", 1000.0) + struct.pack("<I", 2000) + struct.pack(
        "<d", 5.0
    ) + struct.pack("<d", 10.0) + struct.pack("<Q", 123456789)
    assert P.decode(data) == P.HelloReply(7, info)


def test_reading_layout_and_round_trip():
    cu = np.array([-3, 0, 2**40], dtype=np.int64)
    cl = np.array([1, 2, -(2**35)], dtype=np.int64)
    v = np.array([0.5, -1.25, 5.0])
    data = P.encode(P.Reading(9, 1000, cu, cl, v, last_command=41, timed_out=True))
    body = data[12:]
    assert len(data) == 12 + 16 + 3 * 20
    assert body[:16] == struct.pack("<Q", 1000) + struct.pack("<H", 3) + struct.pack("<I", 41) + struct.pack(
        "<H", 1
    )
    for k in range(3):
        s = body[16 + 20 * k : 36 + 20 * k]
        assert s == struct.pack("<q", int(cu[k])) + struct.pack("<q", int(cl[k])) + struct.pack("<f", v[k])
    back = P.decode(data)
    assert isinstance(back, P.Reading)
    assert (back.seq, back.first_tick, back.last_command, back.timed_out) == (9, 1000, 41, True)
    np.testing.assert_array_equal(back.counts_upper, cu)
    np.testing.assert_array_equal(back.counts_lower, cl)
    np.testing.assert_array_equal(back.voltage, v.astype(np.float32))


@pytest.mark.parametrize(
    "msg, body",
    [
        (P.Start(3, 50, 0.15), struct.pack("<H", 50) + struct.pack("<d", 0.15)),
        (P.Command(4, -2.5), struct.pack("<d", -2.5)),
        (P.Stop(5), b""),
        (P.Stopped(5, 77), struct.pack("<Q", 77)),
    ],
)
def test_other_messages(msg, body):
    data = P.encode(msg)
    assert data[12:] == body
    assert P.decode(data) == msg


@pytest.mark.parametrize(
    "data, words",
    [
        (b"DRI", "shorter"),
        (b"XRIG" + bytes([1, 1, 0, 0, 0, 0, 0, 0]), "magic"),
        (b"DRIG" + bytes([2, 1, 0, 0, 0, 0, 0, 0]), "version"),
        (b"DRIG" + bytes([1, 99, 0, 0, 0, 0, 0, 0]), "unknown"),
        (b"DRIG" + bytes([1, 5, 0, 0, 0, 0, 0, 0]) + b"\x00" * 4, "expected"),
        (b"DRIG" + bytes([1, 5, 0, 0, 0, 0, 0, 0]) + struct.pack("<d", float("nan")), "not finite"),
        (
            P.encode(P.Reading(0, 0, np.zeros(2, np.int64), np.zeros(2, np.int64), np.zeros(2)))[:-1],
            "does not hold",
        ),
    ],
)
def test_bad_datagrams_are_refused(data, words):
    with pytest.raises(P.ProtocolError, match=words):
        P.decode(data)
