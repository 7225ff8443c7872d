"""eye_in_hand.io.cdr: sensor_msgs/Image decoded from CDR as a view, checked against rosbags."""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.errors import ConversionError
from eye_in_hand.io.bags import default_typestore, deserialize, serialize
from eye_in_hand.io.cdr import image_from_cdr, is_image_type
from eye_in_hand.ros.images import image_to_numpy
from eye_in_hand.ros.stamps import header_stamp_ns

IMAGE = "sensor_msgs/msg/Image"


def _image_cdr(frame_id: str, encoding: str, h: int, w: int, step: int, data: np.ndarray,
               bigendian: int = 0, sec: int = 1_700_000_000, nsec: int = 123_456_789) -> bytes:
    T = default_typestore().types
    msg = T[IMAGE](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame_id),
        height=h, width=w, encoding=encoding, is_bigendian=bigendian, step=step,
        data=np.ascontiguousarray(data, dtype=np.uint8).ravel())
    return serialize(msg, IMAGE)


@pytest.mark.parametrize("frame_id", ["", "a", "ab", "abc", "abcd", "camera_left_optical_frame"])
@pytest.mark.parametrize("encoding,channels,itemsize,pad", [
    ("bgr8", 3, 1, 0), ("mono8", 1, 1, 3), ("mono16", 1, 2, 0), ("rgba8", 4, 1, 8)])
def test_matches_the_generic_deserializer(frame_id: str, encoding: str, channels: int,
                                          itemsize: int, pad: int) -> None:
    rng = np.random.default_rng(len(frame_id))
    h, w = 5, 7
    step = w * channels * itemsize + pad
    data = rng.integers(0, 256, size=h * step, dtype=np.uint8)
    raw = _image_cdr(frame_id, encoding, h, w, step, data)
    ours = image_from_cdr(raw)
    ref = deserialize(raw, IMAGE)
    assert ours is not None
    assert (ours.height, ours.width, ours.encoding, ours.is_bigendian, ours.step) == \
        (ref.height, ref.width, ref.encoding, ref.is_bigendian, ref.step)
    assert ours.header.frame_id == ref.header.frame_id
    assert header_stamp_ns(ours) == header_stamp_ns(ref) == 1_700_000_000_123_456_789
    np.testing.assert_array_equal(ours.data, ref.data)
    np.testing.assert_array_equal(image_to_numpy(ours), image_to_numpy(ref))


def test_pixels_are_a_read_only_view_of_the_buffer() -> None:
    data = np.arange(2 * 4 * 3, dtype=np.uint8)
    raw = bytearray(_image_cdr("cam", "bgr8", 2, 4, 12, data))
    img = image_from_cdr(memoryview(raw))
    assert img is not None and not img.data.flags.writeable
    raw[-1] = 200                                   # the view sees the buffer
    assert img.data[-1] == 200
    assert image_to_numpy(img).base is not None


def test_big_endian_pixels_flag_is_kept() -> None:
    data = np.arange(2 * 3 * 2, dtype=np.uint8)
    img = image_from_cdr(_image_cdr("", "mono16", 2, 3, 6, data, bigendian=1))
    assert img is not None and img.is_bigendian == 1
    np.testing.assert_array_equal(image_to_numpy(img),
                                  data.view(">u2").reshape(2, 3).astype(np.uint16))


def test_big_endian_cdr_is_left_to_the_generic_deserializer() -> None:
    raw = bytearray(_image_cdr("", "mono8", 1, 1, 1, np.zeros(1)))
    raw[1] = 0x00                                   # encapsulation CDR_BE
    assert image_from_cdr(bytes(raw)) is None
    assert image_from_cdr(b"") is None


@pytest.mark.parametrize("cut", [3, 6, 14, 20, 30, 40, -1])
def test_truncated_message_names_what_is_missing(cut: int) -> None:
    raw = _image_cdr("frame", "bgr8", 2, 2, 6, np.zeros(12))
    with pytest.raises(ConversionError, match=r"header|height|encoding|is_bigendian|step|data"):
        image_from_cdr(raw[:cut] if cut > 4 else raw[:4] + raw[4:4 + cut])


def test_bad_strings_are_conversion_errors() -> None:
    raw = bytearray(_image_cdr("ab", "mono8", 1, 1, 1, np.zeros(1)))
    raw[4 + 8 + 4 + 2] = ord("x")                   # the frame_id's NUL terminator
    with pytest.raises(ConversionError, match="header.frame_id: string is not NUL-terminated"):
        image_from_cdr(bytes(raw))
    raw = bytearray(_image_cdr("ab", "mono8", 1, 1, 1, np.zeros(1)))
    raw[4 + 8:4 + 12] = (10**6).to_bytes(4, "little")
    with pytest.raises(ConversionError, match="header.frame_id: string of 1000000 bytes"):
        image_from_cdr(bytes(raw))


def test_is_image_type() -> None:
    assert is_image_type("sensor_msgs/msg/Image")
    assert not is_image_type("sensor_msgs/msg/CompressedImage")
