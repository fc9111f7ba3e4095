"""The serial frame: known CRC, round trips, resynchronisation, and fuzzing of the decoder."""

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bsjax.device import _frames as frames
from bsjax.device import decode_frames, encode_force, encode_frame, encode_pose


def test_crc_matches_the_ccitt_false_check_value():
    assert frames.crc16(b"123456789") == 0x29B1


def test_pose_and_force_round_trip():
    data = encode_pose(7, (0.1, -0.2, 0.3), (0.5, 0.5, 0.5, 0.5), buttons=1, timestamp_us=123456)
    data += encode_force(65537, (1.5, -2.0, 0.25), (0.0, 0.1, 0.0))
    got = decode_frames(data)
    assert got.rest == b"" and got.dropped == 0 and got.skipped == 0
    pose, force = got.frames
    assert (pose.seq, pose.kind, force.seq, force.kind) == (7, frames.KIND_POSE, 1, frames.KIND_FORCE)
    position, orientation, buttons, stamp = frames.parse_pose(pose.payload)
    np.testing.assert_allclose(position, (0.1, -0.2, 0.3), rtol=1e-6)
    assert orientation == (0.5, 0.5, 0.5, 0.5) and buttons == 1 and stamp == 123456
    f, t = frames.parse_force(force.payload)
    assert f == (1.5, -2.0, 0.25) and t[1] == pytest.approx(0.1)
    assert len(encode_pose(0, (0, 0, 0))) == frames.OVERHEAD + 36


def test_incomplete_frame_waits_in_rest():
    data = encode_pose(1, (1, 2, 3))
    for cut in range(len(data)):
        got = decode_frames(data[:cut])
        assert got.frames == [] and got.rest == data[:cut] and got.dropped == 0
        assert decode_frames(got.rest + data[cut:]).frames[0].seq == 1


def test_truncated_crc_and_malformed_frames_are_counted_and_dropped():
    good1, good2 = encode_pose(1, (0, 0, 1)), encode_pose(2, (0, 0, 2))
    bad_crc = bytearray(encode_pose(3, (0, 0, 3)))
    bad_crc[10] ^= 0xFF
    too_long = bytes([frames.START, 200, 0, 0, 1]) + b"\x00" * 10
    wrong_size = encode_frame(4, frames.KIND_POSE, b"\x00" * 8)  # valid CRC, POSE needs 36 bytes
    unknown = encode_frame(5, 99, b"abc")
    stream = (
        good1
        + encode_pose(9, (0, 0, 9))[:20]
        + bytes(bad_crc)
        + b"junk"
        + too_long
        + wrong_size
        + unknown
        + good2
    )
    got = decode_frames(stream)
    assert [f.seq for f in got.frames] == [1, 2]
    assert got.truncated >= 1 and got.crc_errors >= 1 and got.malformed >= 3
    assert got.rest == b""


def test_encode_rejects_bad_arguments():
    with pytest.raises(ValueError, match="payload"):
        encode_frame(0, 1, b"x" * (frames.MAX_PAYLOAD + 1))
    with pytest.raises(ValueError, match="kind"):
        encode_frame(0, 300, b"")


def test_sequence_numbers_wrap():
    assert frames.seq_newer(0, 65535) and frames.seq_newer(5, None)
    assert not frames.seq_newer(65535, 0) and not frames.seq_newer(3, 3)


def _valid(frame):
    body = struct.pack("<BHB", len(frame.payload), frame.seq, frame.kind) + frame.payload
    return frames.PAYLOAD_SIZE.get(frame.kind) == len(frame.payload), frames.crc16(body)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_decoder_never_raises_and_never_yields_a_bad_frame(data):
    got = decode_frames(data)
    assert len(got.rest) <= len(data)
    for frame in got.frames:
        ok, _crc = _valid(frame)
        assert ok
        # The frame's bytes, re-encoded, occur in the input: its CRC was checked on real bytes.
        assert encode_frame(frame.seq, frame.kind, frame.payload) in data
    assert got.skipped + got.dropped <= len(data)


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(0, 65535),
            st.floats(-1, 1),
            st.binary(max_size=12).map(lambda b: b.replace(bytes([frames.START]), b"")),
        ),
        min_size=1,
        max_size=12,
    ),
    st.lists(st.integers(1, 60), max_size=8),
)
def test_frames_between_garbage_all_recovered_from_any_chunking(items, cuts):
    stream = b"".join(junk + encode_pose(seq, (x, 0.0, -x)) for seq, x, junk in items)
    chunks, start = [], 0
    for c in cuts:
        chunks.append(stream[start : start + c])
        start += c
    chunks.append(stream[start:])
    rest, seqs = b"", []
    for chunk in chunks:
        got = decode_frames(rest + chunk)
        rest = got.rest
        seqs += [f.seq for f in got.frames]
        assert got.dropped == 0
    assert seqs == [seq for seq, _, _ in items]
