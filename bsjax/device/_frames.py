"""The binary frame of the serial haptic protocol: encode, and decode a byte stream robustly.

Every message on the wire is one frame (all integers little-endian):

```
offset   size  field
0        1     START   0xA5
1        1     LEN     payload length in bytes, 0..MAX_PAYLOAD (64)
2        2     SEQ     sequence number, uint16, wraps 65535 → 0
4        1     KIND    1 = POSE (device → host), 2 = FORCE (host → device)
5        LEN   PAYLOAD
5+LEN    2     CRC     CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xor-out)
                       over bytes 1 .. 4+LEN (LEN, SEQ, KIND, PAYLOAD); check("123456789") = 0x29B1
```

Payloads (float32, little-endian):

* POSE, 36 bytes: position `x y z` (device units, metres), orientation quaternion `w x y z`,
  buttons (uint32 bit mask, bit 0 = stylus button), device timestamp (uint32 microseconds, wraps).
* FORCE, 24 bytes: force `fx fy fz` (newtons), torque `tx ty tz` (newton-metres).

A POSE frame is 43 bytes: at 1 kHz it needs 430 kbit/s, so use ≥ 460800 baud on a real UART (USB
CDC-ACM devices ignore the baud rate).

Decoding never raises (on any input, bytes-like or not) and never yields a frame whose CRC does
not match: the decoder scans for START, rejects impossible lengths (counted as `malformed`), waits
for incomplete frames at the end of the buffer (returned in `rest`), and after a CRC mismatch
advances one byte and resynchronises, so a frame cut short by a lost byte costs only itself
(counted as `truncated` when another START byte lies inside the claimed frame, as `crc_errors`
otherwise). Frames of an unknown kind or with a payload length that does not match their kind are
counted as `malformed` and dropped. The encoders refuse non-finite numbers (and numbers beyond the
float32 range): a NaN never goes on the wire from bsjax.
"""

from __future__ import annotations

import binascii
import numbers
import struct
from typing import NamedTuple

import numpy as np

from bsjax._declared import declared

START = 0xA5
MAX_PAYLOAD = 64
KIND_POSE = 1
KIND_FORCE = 2

_HEADER = struct.Struct("<BBHB")  # START, LEN, SEQ, KIND
_CRC = struct.Struct("<H")
_POSE = struct.Struct("<3f4fII")
_FORCE = struct.Struct("<3f3f")
PAYLOAD_SIZE = {KIND_POSE: _POSE.size, KIND_FORCE: _FORCE.size}
OVERHEAD = _HEADER.size + _CRC.size  # 7 bytes around the payload
_FLOAT32_MAX = float(np.finfo(np.float32).max)


class Frame(NamedTuple):
    """One decoded frame with a valid CRC."""

    seq: int
    kind: int
    payload: bytes


class Decoded(NamedTuple):
    """What `decode_frames` found in a buffer.

    `rest` holds the bytes of an incomplete frame at the end (feed them back with the next
    read); the counters say what was dropped.
    """

    frames: list[Frame]
    rest: bytes
    crc_errors: int
    truncated: int
    malformed: int
    skipped: int  # bytes thrown away while looking for START

    @property
    def dropped(self) -> int:
        return self.crc_errors + self.truncated + self.malformed


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of `data` (`binascii.crc_hqx` with init 0xFFFF)."""
    return binascii.crc_hqx(data, 0xFFFF)


@declared
def encode_frame(seq: int, kind: int, payload: bytes) -> bytes:
    """One frame: `START | LEN | SEQ | KIND | PAYLOAD | CRC16` (see the module docstring).

    **Arguments:** `seq` any int (taken modulo 65536); `kind` 0..255; `payload` bytes-like, ≤ 64
    bytes. `TypeError`/`ValueError` naming the argument otherwise.
    """
    seq = _integer(seq, "seq")
    if not 0 <= _integer(kind, "kind") <= 255:
        raise ValueError(f"kind: expected an int in 0..255, got {kind}")
    try:
        payload = bytes(memoryview(payload))
    except TypeError:
        raise TypeError(f"payload: expected bytes-like, got {type(payload).__name__}") from None
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload: expected at most {MAX_PAYLOAD} bytes, got {len(payload)}")
    head = _HEADER.pack(START, len(payload), seq & 0xFFFF, kind)
    return head + payload + _CRC.pack(crc16(head[1:] + payload))


def decode_frames(buffer: bytes | bytearray | memoryview) -> Decoded:
    """All valid frames in `buffer`, the incomplete tail, and counts of what was dropped.

    Never raises, on any input: an object that is not bytes-like (`str`, None, an int, a released
    memoryview …) yields no frames, an empty `rest` and `malformed = 1`. Every returned frame
    passed its CRC and has a known kind with the payload length of that kind.
    """
    try:
        data = bytes(memoryview(buffer))  # buffer protocol only: bytes(5) would make 5 zero bytes
    except Exception:
        return Decoded([], b"", 0, 0, 1, 0)
    frames: list[Frame] = []
    crc_errors = truncated = malformed = skipped = 0
    i, end = 0, len(data)
    while i < end:
        j = data.find(START, i)
        if j < 0:
            skipped += end - i
            i = end
            break
        skipped += j - i
        i = j
        if end - i < _HEADER.size:
            break  # header incomplete: wait for more bytes
        _, length, seq, kind = _HEADER.unpack_from(data, i)
        if length > MAX_PAYLOAD:
            malformed += 1
            i += 1
            continue
        stop = i + _HEADER.size + length + _CRC.size
        if stop > end:
            break  # frame incomplete: wait for more bytes
        body = data[i + 1 : stop - _CRC.size]
        if crc16(body) != _CRC.unpack_from(data, stop - _CRC.size)[0]:
            if data.find(START, i + 1, stop) >= 0:
                truncated += 1
            else:
                crc_errors += 1
            i += 1
            continue
        payload = body[_HEADER.size - 1 :]
        if PAYLOAD_SIZE.get(kind) != len(payload):
            malformed += 1
        else:
            frames.append(Frame(seq, kind, payload))
        i = stop
    return Decoded(frames, data[i:], crc_errors, truncated, malformed, skipped)


@declared
def encode_pose(
    seq: int, position, orientation=(1.0, 0.0, 0.0, 0.0), buttons: int = 0, timestamp_us: int = 0
) -> bytes:
    """A POSE frame (device → host).

    **Arguments:** `seq` int; `position (3,)` metres and `orientation (4,)` quaternion `w x y z`,
    finite and within the float32 range; `buttons` int bit mask and `timestamp_us` int (both taken
    modulo 2³²). `ValueError`/`TypeError` naming the argument otherwise (never NaN on the wire).
    """
    x, y, z = _float32s(position, "position", 3)
    w, qx, qy, qz = _float32s(orientation, "orientation", 4)
    buttons, stamp = _integer(buttons, "buttons"), _integer(timestamp_us, "timestamp_us")
    payload = _POSE.pack(x, y, z, w, qx, qy, qz, buttons & 0xFFFFFFFF, stamp & 0xFFFFFFFF)
    return encode_frame(seq, KIND_POSE, payload)


@declared
def encode_force(seq: int, force, torque=(0.0, 0.0, 0.0)) -> bytes:
    """A FORCE frame (host → device): `force (3,)` newtons and `torque (3,)` newton-metres, finite
    and within the float32 range (`ValueError`/`TypeError` naming the argument otherwise)."""
    payload = _FORCE.pack(*_float32s(force, "force", 3), *_float32s(torque, "torque", 3))
    return encode_frame(seq, KIND_FORCE, payload)


def _integer(value, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name}: expected an int, got {type(value).__name__} {value!r}")
    return int(value)


def _float32s(values, name: str, count: int) -> tuple[float, ...]:
    """`count` real numbers, finite and representable in float32, as Python floats."""
    try:
        a = np.asarray(values)
    except Exception:
        a = np.asarray(None)
    if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise TypeError(f"{name}: expected {count} real numbers, got {values!r}")
    if a.shape != (count,):
        raise ValueError(f"{name}: expected {count} numbers (shape ({count},)), got shape {a.shape}")
    out = tuple(float(v) for v in a)
    if not all(abs(v) <= _FLOAT32_MAX for v in out):  # False for NaN: refuse NaN, inf, overflow
        raise ValueError(f"{name}: expected {count} finite float32 numbers (|x| <= 3.4e38), got {out}")
    return out


def parse_pose(
    payload: bytes,
) -> tuple[tuple[float, float, float], tuple[float, float, float, float], int, int]:
    """POSE payload → `(position, orientation wxyz, buttons, timestamp_us)`."""
    v = _POSE.unpack(payload)
    return v[0:3], v[3:7], v[7], v[8]


def parse_force(payload: bytes) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """FORCE payload → `(force, torque)`."""
    v = _FORCE.unpack(payload)
    return v[0:3], v[3:6]


def seq_newer(seq: int, last: int | None) -> bool:
    """True when uint16 `seq` comes after `last` (serial-number arithmetic, RFC 1982)."""
    if last is None:
        return True
    d = (seq - last) & 0xFFFF
    return 0 < d < 0x8000
