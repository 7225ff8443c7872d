"""eye_in_hand.io.cdr: sensor_msgs/Image decoded from CDR as a view; the fields of
geometry_msgs/PoseStamped, PointStamped, PoseWithCovarianceStamped and of the markers of a
visualization_msgs/MarkerArray read directly; all checked against rosbags."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from eye_in_hand.errors import ConversionError
from eye_in_hand.io.bags import default_typestore, deserialize, serialize
from eye_in_hand.io.cdr import (
    image_from_cdr,
    is_image_type,
    marker_array_from_cdr,
    point_stamped_from_cdr,
    pose_cov_stamped_from_cdr,
    pose_stamped_from_cdr,
)
from eye_in_hand.ros.geometry import point_stamped_fields, pose_cov_stamped_fields
from eye_in_hand.ros.images import image_to_numpy
from eye_in_hand.ros.markers import marker_array_fields
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


POSE = "geometry_msgs/msg/PoseStamped"
#: the seven numbers of a pose: plain, signed zero, extremes, subnormal and non-finite (the
#: decoder passes them through; the caller checks them)
POSE_VALUES = [
    (0.4, -0.1, 0.5, 0.0, 0.0, 0.0, 1.0),
    (-0.0, 1e-310, -1.7976931348623157e308, 0.5, -0.5, 0.5, -0.5),
    (float("nan"), float("inf"), -float("inf"), 1.0, 2.0, 3.0, 4.0),
    (1e300, -1e-300, 123.456, 0.70710678, 0.0, -0.70710678, 1e-17),
]


def _pose_cdr(frame_id: str, values: tuple[float, ...], sec: int = 1_700_000_000,
              nsec: int = 123_456_789, little_endian: bool = True) -> bytes:
    T = default_typestore().types
    x, y, z, qx, qy, qz, qw = values
    msg = T[POSE](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame_id),
        pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z),
            orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)))
    return bytes(default_typestore().serialize_cdr(msg, POSE, little_endian=little_endian))


def _bits(values: tuple[float, ...]) -> bytes:
    return struct.pack("<7d", *values)


# every string length 0-8 puts the pose at each offset the 8-byte alignment can give
@pytest.mark.parametrize("frame_id", ["", "a", "ab", "abc", "abcd", "abcde", "abcdef",
                                      "abcdefg", "base_link", "/world/ünïcode"])
@pytest.mark.parametrize("values", POSE_VALUES)
@pytest.mark.parametrize("sec,nsec", [(1_700_000_000, 123_456_789), (-5, 0),
                                      (2**31 - 1, 2**32 - 1)])
def test_pose_stamped_matches_the_generic_deserializer(frame_id: str, values: tuple[float, ...],
                                                      sec: int, nsec: int) -> None:
    raw = _pose_cdr(frame_id, values, sec, nsec)
    ref = deserialize(raw, POSE)
    got = pose_stamped_from_cdr(raw)
    assert got is not None
    p, o = ref.pose.position, ref.pose.orientation
    assert got[:3] == (ref.header.stamp.sec, ref.header.stamp.nanosec, ref.header.frame_id) \
        == (sec, nsec, frame_id)
    assert _bits(got[3]) == _bits((p.x, p.y, p.z, o.x, o.y, o.z, o.w)) == _bits(values)
    from_view = pose_stamped_from_cdr(memoryview(bytearray(raw)))
    assert from_view is not None
    assert from_view[:3] == got[:3] and _bits(from_view[3]) == _bits(got[3])


def test_pose_stamped_big_endian_is_left_to_the_generic_deserializer() -> None:
    raw = _pose_cdr("base_link", POSE_VALUES[0], little_endian=False)
    assert raw[:2] == b"\x00\x00"
    assert pose_stamped_from_cdr(raw) is None
    assert pose_stamped_from_cdr(b"\x00") is None


@pytest.mark.parametrize("frame_id", ["", "abc", "base_link"])
def test_pose_stamped_truncated_anywhere_names_what_is_missing(frame_id: str) -> None:
    raw = _pose_cdr(frame_id, POSE_VALUES[0])
    for cut in range(4, len(raw)):
        with pytest.raises(ConversionError, match=r"^(header|header\.frame_id|pose): "):
            pose_stamped_from_cdr(raw[:cut])


def test_pose_stamped_bad_frame_string_is_a_conversion_error() -> None:
    raw = bytearray(_pose_cdr("ab", POSE_VALUES[0]))
    raw[4 + 8 + 4 + 2] = ord("x")                   # the frame_id's NUL terminator
    with pytest.raises(ConversionError, match="header.frame_id: string is not NUL-terminated"):
        pose_stamped_from_cdr(bytes(raw))


# -- what hand_eye reads from a detector: PointStamped, PoseWithCovarianceStamped, MarkerArray --
POINT = "geometry_msgs/msg/PointStamped"
POSE_COV = "geometry_msgs/msg/PoseWithCovarianceStamped"
MARKERS = "visualization_msgs/msg/MarkerArray"
FRAMES = ["", "a", "ab", "abc", "abcd", "abcde", "abcdef", "abcdefg",
          "camera_left_optical_frame", "/wörld"]


def _t() -> dict:
    return default_typestore().types


def _header(frame_id: str, sec: int = 1_700_000_000, nsec: int = 123_456_789) -> object:
    T = _t()
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                    frame_id=frame_id)


def _ser(msg: object, msgtype: str, little_endian: bool = True) -> bytes:
    return bytes(default_typestore().serialize_cdr(msg, msgtype, little_endian=little_endian))


def _point_cdr(frame_id: str, xyz: tuple[float, ...], **kw: bool) -> bytes:
    T = _t()
    return _ser(T[POINT](header=_header(frame_id), point=T["geometry_msgs/msg/Point"](
        x=xyz[0], y=xyz[1], z=xyz[2])), POINT, **kw)


def _pose_cov_cdr(frame_id: str, values: tuple[float, ...], cov: np.ndarray, **kw: bool
                  ) -> bytes:
    T = _t()
    x, y, z, qx, qy, qz, qw = values
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z),
        orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))
    return _ser(T[POSE_COV](header=_header(frame_id), pose=T[
        "geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov)), POSE_COV, **kw)


def _fbits(values: tuple[float, ...] | list[float]) -> bytes:
    return struct.pack(f"<{len(values)}d", *values)


@pytest.mark.parametrize("frame_id", FRAMES)
@pytest.mark.parametrize("values", POSE_VALUES)
def test_point_stamped_matches_the_generic_deserializer(frame_id: str,
                                                       values: tuple[float, ...]) -> None:
    raw = _point_cdr(frame_id, values[:3])
    got = point_stamped_from_cdr(raw)
    ref = point_stamped_fields(deserialize(raw, POINT))
    assert got is not None
    assert got[:3] == ref[:3] == (1_700_000_000, 123_456_789, frame_id)
    assert _fbits(got[3]) == _fbits(ref[3]) == _fbits(values[:3])


@pytest.mark.parametrize("frame_id", FRAMES)
@pytest.mark.parametrize("values", POSE_VALUES)
def test_pose_cov_stamped_matches_the_generic_deserializer(frame_id: str,
                                                          values: tuple[float, ...]) -> None:
    cov = np.random.default_rng(len(frame_id)).normal(size=36)
    cov[7] = np.nan
    raw = _pose_cov_cdr(frame_id, values, cov)
    got = pose_cov_stamped_from_cdr(raw)
    ref = pose_cov_stamped_fields(deserialize(raw, POSE_COV))
    assert got is not None
    assert got[:3] == ref[:3] == (1_700_000_000, 123_456_789, frame_id)
    assert _fbits(got[3]) == _fbits(ref[3]) == _fbits(values)
    assert _fbits(got[4]) == _fbits(ref[4]) == _fbits(list(cov))


def _marker(k: int, frame_id: str = "camera_left_optical_frame", **fields: object) -> object:
    """A marker with every variable-length field filled to a length that depends on ``k`` (each
    alignment case of the fields after it comes up over k = 0..7)."""
    T = _t()
    rng = np.random.default_rng(k)
    point = T["geometry_msgs/msg/Point"]
    rgba = T["std_msgs/msg/ColorRGBA"]
    base = dict(
        header=_header(frame_id, 1_700_000_000 + k, 1000 * k), ns=f"t{'x' * k}", id=k,
        type=2, action=0,
        pose=T["geometry_msgs/msg/Pose"](
            position=point(x=0.1 * k, y=-0.2, z=0.5 + k),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
        scale=T["geometry_msgs/msg/Vector3"](x=0.07 + k, y=0.08, z=0.09),
        color=rgba(r=0.25 * (k % 4), g=0.5, b=1.0 / (k + 3), a=1.0),
        lifetime=T["builtin_interfaces/msg/Duration"](sec=k, nanosec=5),
        frame_locked=bool(k % 2),
        points=[point(x=float(i), y=2.0, z=3.0) for i in range(k % 3)],
        colors=[rgba(r=0.1, g=0.2, b=0.3, a=0.4) for _ in range(k % 2 * 2)],
        texture_resource="r" * (k % 5),
        texture=T["sensor_msgs/msg/CompressedImage"](
            header=_header("t" * (k % 3)), format="png"[: k % 4],
            data=rng.integers(0, 256, size=k % 7, dtype=np.uint8)),
        uv_coordinates=[T["visualization_msgs/msg/UVCoordinate"](u=0.5, v=0.25)
                        for _ in range(k % 4)],
        text="hello"[: k % 6], mesh_resource="m" * (k % 3),
        mesh_file=T["visualization_msgs/msg/MeshFile"](
            filename="f" * (k % 4), data=rng.integers(0, 256, size=(3 * k) % 5,
                                                      dtype=np.uint8)),
        mesh_use_embedded_materials=bool(k % 3 == 1))
    base.update(fields)
    return T["visualization_msgs/msg/Marker"](**base)


def _markers_cdr(markers: list, **kw: bool) -> bytes:
    return _ser(_t()[MARKERS](markers=markers), MARKERS, **kw)


def _same_marker_fields(got: list, ref: list) -> None:
    assert len(got) == len(ref)
    for g, r in zip(got, ref, strict=True):
        assert g[:6] == r[:6]
        assert _fbits(g[6]) == _fbits(r[6]) and _fbits([g[7]]) == _fbits([r[7]])
        assert struct.pack("<4f", *g[8]) == struct.pack("<4f", *r[8])


@pytest.mark.parametrize("k", range(8))
def test_marker_array_matches_the_generic_deserializer(k: int) -> None:
    # one to three markers, each with its variable-length fields of other lengths, and a
    # DELETEALL in front as detectors send it
    markers = [_marker(0, type=0, action=3, ns="")] + [_marker(k + i) for i in range(1 + k % 3)]
    raw = _markers_cdr(markers)
    got = marker_array_from_cdr(raw)
    ref = marker_array_fields(deserialize(raw, MARKERS))
    assert got is not None
    _same_marker_fields(got, ref)
    assert [g[3] for g in got][1:] == [f"t{'x' * (k + i)}" for i in range(1 + k % 3)]
    assert marker_array_from_cdr(memoryview(bytearray(raw))) == got


def test_empty_marker_array_is_an_empty_list() -> None:
    assert marker_array_from_cdr(_markers_cdr([])) == []


@pytest.mark.parametrize("reader,raw", [
    (point_stamped_from_cdr, _point_cdr("cam", (1.0, 2.0, 3.0), little_endian=False)),
    (pose_cov_stamped_from_cdr, _pose_cov_cdr("cam", POSE_VALUES[0], np.zeros(36),
                                              little_endian=False)),
    (marker_array_from_cdr, _markers_cdr([_marker(3)], little_endian=False)),
])
def test_big_endian_is_left_to_the_generic_deserializer(reader, raw: bytes) -> None:
    assert raw[:2] == b"\x00\x00"
    assert reader(raw) is None
    assert reader(b"\x00") is None


@pytest.mark.parametrize("reader,raw", [
    (point_stamped_from_cdr, _point_cdr("abc", (1.0, 2.0, 3.0))),
    (pose_cov_stamped_from_cdr, _pose_cov_cdr("abc", POSE_VALUES[0], np.ones(36))),
    (marker_array_from_cdr, _markers_cdr([_marker(5), _marker(2)])),
])
def test_truncated_anywhere_is_a_conversion_error(reader, raw: bytes) -> None:
    # every cut inside the message: an error that names the field, never a short read
    for cut in range(4, len(raw)):
        with pytest.raises(ConversionError, match=r"^(header|point|pose|markers)"):
            reader(raw[:cut])


def test_marker_count_beyond_the_message_is_a_conversion_error() -> None:
    raw = bytearray(_markers_cdr([_marker(1)]))
    raw[4:8] = (10**6).to_bytes(4, "little")
    with pytest.raises(ConversionError, match="markers: 1000000 markers do not fit"):
        marker_array_from_cdr(bytes(raw))


def test_marker_sequence_length_beyond_the_message_is_a_conversion_error() -> None:
    # markers[0].points is the first sequence after the 80 bytes of pose and scale
    raw = bytearray(_markers_cdr([_marker(0, points=[])]))
    body = raw[4:]
    pos = body.index(struct.pack("<4f", 0.0, 0.5, 1.0 / 3, 1.0)) + 16 + 8 + 1
    pos = (pos + 3) & ~3
    assert struct.unpack_from("<I", body, pos) == (0,)
    raw[4 + pos:4 + pos + 4] = (10**6).to_bytes(4, "little")
    with pytest.raises(ConversionError, match=r"markers\[0\]\.points: 1000000 elements"):
        marker_array_from_cdr(bytes(raw))


@pytest.mark.parametrize("reader,raw", [
    (pose_stamped_from_cdr, _pose_cdr("abc", POSE_VALUES[0])),
    (point_stamped_from_cdr, _point_cdr("abc", (1.0, 2.0, 3.0))),
    (pose_cov_stamped_from_cdr, _pose_cov_cdr("abc", POSE_VALUES[0], np.ones(36))),
    (marker_array_from_cdr, _markers_cdr([_marker(5), _marker(2)])),
])
def test_bytes_after_the_last_field_are_refused_as_rosbags_does(reader, raw: bytes) -> None:
    assert reader(raw + b"\x00" * 3) is not None           # padding
    with pytest.raises(ConversionError, match=r"4 bytes after its last field"):
        reader(raw + b"\x00" * 4)
    with pytest.raises(Exception):                          # noqa: B017 - rosbags' own error
        deserialize(raw + b"\x00" * 8, {pose_stamped_from_cdr: POSE,
                                        point_stamped_from_cdr: POINT,
                                        pose_cov_stamped_from_cdr: POSE_COV}.get(reader, MARKERS))


def test_a_marker_count_lowered_is_refused() -> None:
    # two markers announced as one: the second would be dropped without a word
    raw = bytearray(_markers_cdr([_marker(1), _marker(2)]))
    raw[4:8] = (1).to_bytes(4, "little")
    with pytest.raises(ConversionError, match=r"^markers\[0\]: \d+ bytes after its last field"):
        marker_array_from_cdr(bytes(raw))


@pytest.mark.parametrize("bad,match", [(b"\xffk\x00", "not UTF-8"),
                                       (b"okk", "not NUL-terminated")])
def test_a_bad_string_in_a_field_the_node_does_not_use_is_refused(bad: bytes,
                                                                  match: str) -> None:
    raw = _markers_cdr([_marker(1, text="ok"), _marker(2)])
    assert raw.count(b"ok\x00") == 1
    bad_raw = raw.replace(b"ok\x00", bad)
    assert len(bad_raw) == len(raw)
    with pytest.raises(ConversionError, match=rf"^markers\[0\]\.text: (string is )?{match}"):
        marker_array_from_cdr(bad_raw)


def test_an_empty_string_without_its_nul_is_refused() -> None:
    raw = bytearray(_point_cdr("", (1.0, 2.0, 3.0)))
    assert raw[4 + 8:4 + 13] == b"\x01\x00\x00\x00\x00"     # frame_id "": length 1, its NUL
    raw[4 + 12] = ord("x")
    with pytest.raises(ConversionError, match="header.frame_id: string is not NUL-terminated"):
        point_stamped_from_cdr(bytes(raw))
