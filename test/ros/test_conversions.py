"""Tests of the message conversions (eye_in_hand.ros.stamps, images, camera_info, geometry)
on rclpy messages, rosbags messages and CDR bytes."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from eye_in_hand.core.camera import CameraModel
from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.errors import ConversionError
from eye_in_hand.ros.camera_info import camera_info_to_model, model_to_camera_info
from eye_in_hand.ros.geometry import (
    matrix_to_pose,
    matrix_to_pose_stamped,
    matrix_to_transform_stamped,
    point_to_xyz,
    pose_to_matrix,
    transform_to_matrix,
    xyz_to_point,
    xyz_to_point_stamped,
)
from eye_in_hand.ros.images import (
    calibration_image,
    compressed_to_numpy,
    image_to_numpy,
    numpy_to_compressed,
    numpy_to_image,
)
from eye_in_hand.ros.stamps import header_stamp_ns, make_header, ns_to_stamp, stamp_to_ns

pytest.importorskip("rclpy")

ENCODINGS = {
    "mono8": (np.uint8, 1), "mono16": (np.uint16, 1), "bgr8": (np.uint8, 3),
    "rgb8": (np.uint8, 3), "bgra8": (np.uint8, 4), "rgba8": (np.uint8, 4),
    "8UC1": (np.uint8, 1), "8UC3": (np.uint8, 3), "16UC1": (np.uint16, 1),
    "32FC1": (np.float32, 1), "bayer_rggb8": (np.uint8, 1), "bayer_grbg8": (np.uint8, 1),
    "bgr16": (np.uint16, 3),
}


def random_image(rng: np.random.Generator, encoding: str, h: int = 7, w: int = 5) -> np.ndarray:
    dtype, ch = ENCODINGS[encoding]
    shape = (h, w) if ch == 1 else (h, w, ch)
    if dtype == np.float32:
        return rng.normal(size=shape).astype(np.float32)
    return rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True).astype(dtype)


def rosbags_image(typestore, arr_bytes: np.ndarray, *, height: int, width: int, step: int,
                  encoding: str, bigendian: int = 0, stamp=(12, 345)):
    Image = typestore.types["sensor_msgs/msg/Image"]
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    return Image(header=Header(stamp=Time(sec=stamp[0], nanosec=stamp[1]), frame_id="cam"),
                 height=height, width=width, encoding=encoding, is_bigendian=bigendian,
                 step=step, data=arr_bytes)


# -- images -----------------------------------------------------------------------------------
@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_image_round_trip_rclpy_is_zero_copy(encoding):
    rng = np.random.default_rng(1)
    img = random_image(rng, encoding)
    msg = numpy_to_image(img, encoding, stamp_ns=5_000_000_123, frame_id="cam")
    assert msg.encoding == encoding
    assert msg.step == img.shape[1] * img.itemsize * (img.shape[2] if img.ndim == 3 else 1)
    assert header_stamp_ns(msg) == 5_000_000_123 and msg.header.frame_id == "cam"
    out = image_to_numpy(msg)
    assert out.dtype == img.dtype and out.shape == img.shape
    np.testing.assert_array_equal(out, img)
    assert np.shares_memory(out, np.frombuffer(msg.data, dtype=np.uint8))
    copied = image_to_numpy(msg, copy=True)
    assert not np.shares_memory(copied, np.frombuffer(msg.data, dtype=np.uint8))


@pytest.mark.parametrize("encoding,pad", [("mono8", 3), ("bgr8", 1), ("mono16", 6),
                                          ("rgba8", 4), ("32FC1", 4)])
def test_padded_rows_rosbags_message_decode_as_view(typestore, encoding, pad):
    rng = np.random.default_rng(2)
    img = random_image(rng, encoding, h=6, w=9)
    row = img.shape[1] * img.itemsize * (img.shape[2] if img.ndim == 3 else 1)
    step = row + pad
    raw = rng.integers(0, 255, size=(img.shape[0], step), endpoint=True).astype(np.uint8)
    raw[:, :row] = np.frombuffer(np.ascontiguousarray(img).astype(img.dtype.newbyteorder("<"))
                                 .tobytes(), np.uint8).reshape(img.shape[0], row)
    data = raw.reshape(-1)
    msg = rosbags_image(typestore, data, height=img.shape[0], width=img.shape[1], step=step,
                        encoding=encoding)
    out = image_to_numpy(msg)
    np.testing.assert_array_equal(out, img)
    assert np.shares_memory(out, data)  # padding is skipped by strides, not copied
    assert header_stamp_ns(msg) == 12 * 10**9 + 345


def test_padded_rows_with_colour_conversion(typestore):
    rng = np.random.default_rng(12)
    img = random_image(rng, "bgr8", h=5, w=7)
    raw = np.zeros((5, 7 * 3 + 3), np.uint8)
    raw[:, :21] = img.reshape(5, 21)
    msg = rosbags_image(typestore, raw.reshape(-1), height=5, width=7, step=24, encoding="bgr8")
    np.testing.assert_array_equal(image_to_numpy(msg, desired_encoding="rgb8"),
                                  img[:, :, ::-1])
    mosaic = rosbags_image(typestore, rng.integers(0, 255, 4 * 13, dtype=np.uint8), height=4,
                           width=10, step=13, encoding="bayer_rggb8")
    assert image_to_numpy(mosaic, desired_encoding="bgr8").shape == (4, 10, 3)


@pytest.mark.parametrize("encoding", ["mono16", "16UC1", "bgr16"])
def test_big_endian_16_bit_is_byte_swapped(typestore, encoding):
    rng = np.random.default_rng(3)
    img = random_image(rng, encoding, h=4, w=6)
    ch = img.shape[2] if img.ndim == 3 else 1
    pad = 2
    step = img.shape[1] * 2 * ch + pad
    raw = np.zeros((img.shape[0], step), np.uint8)
    raw[:, :step - pad] = np.frombuffer(img.astype(">u2").tobytes(), np.uint8).reshape(
        img.shape[0], -1)
    msg = rosbags_image(typestore, raw.reshape(-1), height=img.shape[0], width=img.shape[1],
                        step=step, encoding=encoding, bigendian=1)
    out = image_to_numpy(msg)
    assert out.dtype == np.dtype("=u2")
    np.testing.assert_array_equal(out, img)
    # The same bytes read as little endian would be wrong: the flag is honoured.
    msg.is_bigendian = 0
    assert not np.array_equal(image_to_numpy(msg), img)


def test_bytes_data_decodes_read_only_view():
    rng = np.random.default_rng(4)
    img = random_image(rng, "bgr8")

    class Msg:  # duck-typed: any object with the Image fields
        height, width, encoding, is_bigendian, step = 7, 5, "bgr8", 0, 15
        data = img.tobytes()

    out = image_to_numpy(Msg())
    np.testing.assert_array_equal(out, img)
    assert not out.flags.writeable


def test_rclpy_serialize_round_trip_and_rosbags_deserialize(typestore):
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Image

    rng = np.random.default_rng(5)
    img = random_image(rng, "rgb8", h=33, w=17)
    msg = numpy_to_image(img, "rgb8", stamp_ns=1_700_000_000_123_456_789, frame_id="left")
    raw = serialize_message(msg)
    back = deserialize_message(raw, Image)
    np.testing.assert_array_equal(image_to_numpy(back), img)
    assert header_stamp_ns(back) == 1_700_000_000_123_456_789
    # rosbags reads the same CDR bytes (as it does from a bag): data is a numpy uint8 array.
    rb = typestore.deserialize_cdr(raw, "sensor_msgs/msg/Image")
    assert isinstance(rb.data, np.ndarray)
    out = image_to_numpy(rb)
    np.testing.assert_array_equal(out, img)
    assert np.shares_memory(out, rb.data)
    assert header_stamp_ns(rb) == 1_700_000_000_123_456_789
    # and rosbags-serialized bytes deserialize in rclpy.
    again = deserialize_message(bytes(typestore.serialize_cdr(rb, "sensor_msgs/msg/Image")),
                                Image)
    np.testing.assert_array_equal(image_to_numpy(again), img)


def test_colour_conversions():
    rng = np.random.default_rng(6)
    bgr = random_image(rng, "bgr8")
    msg = numpy_to_image(bgr, "bgr8")
    np.testing.assert_array_equal(image_to_numpy(msg, desired_encoding="rgb8"),
                                  bgr[:, :, ::-1])
    rgba = image_to_numpy(msg, desired_encoding="rgba8")
    np.testing.assert_array_equal(rgba[:, :, :3], bgr[:, :, ::-1])
    assert np.all(rgba[:, :, 3] == 255)
    grey = image_to_numpy(msg, desired_encoding="mono8")
    expected = np.rint(bgr @ np.array([0.114, 0.587, 0.299]))
    assert grey.shape == bgr.shape[:2] and np.max(np.abs(grey - expected)) <= 1
    mono = numpy_to_image(grey, "mono8")
    assert np.all(image_to_numpy(mono, desired_encoding="bgr8") == grey[:, :, None])
    # A generic alias relabels without copying.
    generic = numpy_to_image(bgr, "8UC3")
    out = image_to_numpy(generic, desired_encoding="bgr8")
    assert np.shares_memory(out, np.frombuffer(generic.data, np.uint8))
    with pytest.raises(ConversionError, match="desired_encoding.*mono16 to mono8"):
        image_to_numpy(numpy_to_image(np.zeros((2, 2), np.uint16)),
                            desired_encoding="mono8")
    with pytest.raises(ConversionError, match="desired_encoding: unsupported.*yuv422"):
        image_to_numpy(msg, desired_encoding="yuv422")


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer_demosaic_recovers_a_flat_colour(pattern):
    h, w = 16, 20
    bgr = {"b": 40, "g": 120, "r": 200}
    mosaic = np.zeros((h, w), np.uint8)
    for k, (dy, dx) in enumerate([(0, 0), (0, 1), (1, 0), (1, 1)]):
        mosaic[dy::2, dx::2] = bgr[pattern[k]]
    msg = numpy_to_image(mosaic, f"bayer_{pattern}8")
    np.testing.assert_array_equal(image_to_numpy(msg), mosaic)
    out = image_to_numpy(msg, desired_encoding="bgr8")
    np.testing.assert_array_equal(out[4:-4, 4:-4].reshape(-1, 3).min(axis=0), (40, 120, 200))
    np.testing.assert_array_equal(out[4:-4, 4:-4].reshape(-1, 3).max(axis=0), (40, 120, 200))
    rgb = image_to_numpy(msg, desired_encoding="rgb8")
    np.testing.assert_array_equal(rgb[8, 8], (200, 120, 40))


def _image_msg(**fields):
    class Msg:
        height, width, encoding, is_bigendian, step = 4, 3, "mono8", 0, 3
        data = np.zeros(12, np.uint8)

    msg = Msg()
    for k, v in fields.items():
        setattr(msg, k, v)
    return msg


@pytest.mark.parametrize("fields,match", [
    ({"data": np.zeros(11, np.uint8)}, r"^data: length 11 does not match height \* step"),
    ({"step": 2}, r"^step: 2 is shorter than a row"),
    ({"encoding": "yuv422"}, r"^encoding: unsupported image encoding 'yuv422'"),
    ({"height": 0, "data": np.zeros(0, np.uint8)}, r"^height/width: empty"),
    ({"encoding": "mono16"}, r"^step: 3 is shorter"),
    ({"data": np.zeros(12, np.float32)}, r"^data: expected uint8 data"),
    ({"height": 4.5}, r"^height: expected an integer"),
    ({"encoding": None}, r"^encoding: expected a string"),
])
def test_malformed_image_messages_name_the_field(fields, match):
    with pytest.raises(ConversionError, match=match):
        image_to_numpy(_image_msg(**fields))


def test_missing_field_is_named():
    class NotAnImage:
        height, width, step, is_bigendian, encoding = 1, 1, 1, 0, "mono8"

    with pytest.raises(ConversionError, match=r"^data: missing field"):
        image_to_numpy(NotAnImage())


def test_numpy_to_image_validation_and_inference():
    assert numpy_to_image(np.zeros((2, 3), np.uint8)).encoding == "mono8"
    assert numpy_to_image(np.zeros((2, 3, 3), np.uint8)).encoding == "bgr8"
    assert numpy_to_image(np.zeros((2, 3, 4), np.uint8)).encoding == "bgra8"
    assert numpy_to_image(np.zeros((2, 3), np.uint16)).encoding == "mono16"
    assert numpy_to_image(np.zeros((2, 3, 1), np.uint8), "mono8").width == 3
    big = np.arange(6, dtype=">u2").reshape(2, 3)
    np.testing.assert_array_equal(image_to_numpy(numpy_to_image(big)), big)
    with pytest.raises(ConversionError, match="dtype uint16 does not match encoding bgr8"):
        numpy_to_image(np.zeros((2, 3, 3), np.uint16), "bgr8")
    with pytest.raises(ConversionError, match=r"shape \(2, 3\) does not match encoding rgb8"):
        numpy_to_image(np.zeros((2, 3), np.uint8), "rgb8")
    with pytest.raises(ConversionError, match="cannot infer an encoding"):
        numpy_to_image(np.zeros((2, 3), np.float64))
    with pytest.raises(ConversionError, match="^encoding: unsupported"):
        numpy_to_image(np.zeros((2, 3), np.uint8), "jpeg")
    with pytest.raises(ConversionError, match="stamp_ns"):
        numpy_to_image(np.zeros((2, 3), np.uint8), stamp_ns=1.5)


# -- compressed images ------------------------------------------------------------------------
def smooth_bgr(h: int = 48, w: int = 64) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([x * 255 // w, y * 255 // h, (x + y) * 255 // (w + h)], -1).astype(np.uint8)


@pytest.mark.parametrize("encoding", ["mono8", "bgr8", "rgb8", "bgra8", "rgba8", "mono16",
                                      "bgr16", "bayer_grbg8"])
def test_png_round_trip_is_lossless(encoding):
    rng = np.random.default_rng(7)
    img = random_image(rng, encoding, h=12, w=10)
    msg = numpy_to_compressed(img, "png", encoding=encoding, stamp_ns=42, frame_id="f")
    assert msg.format.startswith(f"{encoding}; png compressed ")
    assert header_stamp_ns(msg) == 42
    out = compressed_to_numpy(msg)
    assert out.dtype == img.dtype
    np.testing.assert_array_equal(out, img)


@pytest.mark.parametrize("encoding", ["bgr8", "rgb8", "mono8"])
def test_jpeg_round_trip_is_close(encoding):
    bgr = smooth_bgr()
    img = {"bgr8": bgr, "rgb8": bgr[:, :, ::-1].copy(), "mono8": bgr[:, :, 1].copy()}[encoding]
    msg = numpy_to_compressed(img, "jpeg", encoding=encoding, jpeg_quality=95)
    raw = "mono8" if encoding == "mono8" else "bgr8"
    assert msg.format == f"{encoding}; jpeg compressed {raw}"
    out = compressed_to_numpy(msg)
    assert out.shape == img.shape
    assert np.mean(np.abs(out.astype(int) - img)) < 2.0  # channel order restored, not swapped
    bgr_out = compressed_to_numpy(msg, desired_encoding="bgr8")
    if encoding == "rgb8":
        assert np.mean(np.abs(bgr_out.astype(int) - bgr)) < 2.0


def test_compressed_plain_formats_and_rosbags_message(typestore):
    img = smooth_bgr()
    png = numpy_to_compressed(img, "png")
    CompressedImage = typestore.types["sensor_msgs/msg/CompressedImage"]
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    data = np.frombuffer(png.data, np.uint8).copy()
    for fmt in ("png", "PNG", ""):
        rb = CompressedImage(header=Header(stamp=Time(sec=1, nanosec=2), frame_id=""),
                             format=fmt, data=data)
        np.testing.assert_array_equal(compressed_to_numpy(rb), img)
    with pytest.raises(ConversionError, match="^format: unsupported compressed image format"):
        compressed_to_numpy(CompressedImage(header=rb.header, format="tiff", data=data))
    with pytest.raises(ConversionError, match="^data: 10 bytes could not be decoded as png"):
        compressed_to_numpy(CompressedImage(header=rb.header, format="png",
                                                 data=data[:10]))
    with pytest.raises(ConversionError, match="^data: empty"):
        compressed_to_numpy(CompressedImage(header=rb.header, format="png",
                                                 data=np.zeros(0, np.uint8)))


def test_numpy_to_compressed_refusals():
    with pytest.raises(ConversionError, match="^format: unsupported"):
        numpy_to_compressed(smooth_bgr(), "webp")
    with pytest.raises(ConversionError, match="JPEG takes 8-bit"):
        numpy_to_compressed(np.zeros((4, 4), np.uint16), "jpeg")
    with pytest.raises(ConversionError, match="JPEG takes 8-bit"):
        numpy_to_compressed(np.zeros((4, 4, 4), np.uint8), "jpeg")
    with pytest.raises(ConversionError, match="jpeg_quality"):
        numpy_to_compressed(smooth_bgr(), "jpeg", jpeg_quality=101)


# -- camera info ------------------------------------------------------------------------------
def make_model(model: str = "plumb_bob") -> CameraModel:
    K = np.array([[612.5, 0.0, 318.2], [0.0, 611.9, 243.7], [0.0, 0.0, 1.0]])
    n = 5 if model == "plumb_bob" else 8
    dist = np.linspace(-0.2, 0.1, n)
    rv = np.array([0.01, -0.02, 0.005])
    R = from_rotvec(rv)[:3, :3]
    P = np.array([[600.0, 0.0, 320.0, -36.0], [0.0, 600.0, 240.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    return CameraModel(K=K, dist=dist, width=640, height=480, distortion_model=model, R=R, P=P)


@pytest.mark.parametrize("model", ["plumb_bob", "rational_polynomial"])
def test_camera_info_round_trip_rclpy_and_rosbags(typestore, model):
    from rclpy.serialization import serialize_message

    cam = make_model(model)
    msg = model_to_camera_info(cam, stamp_ns=77, frame_id="camera_left_optical_frame")
    assert msg.distortion_model == model and len(msg.d) == len(cam.dist)
    for source in (msg, typestore.deserialize_cdr(serialize_message(msg),
                                                  "sensor_msgs/msg/CameraInfo")):
        back = camera_info_to_model(source, name="left")
        assert back.name == "left" and back.distortion_model == model
        assert (back.width, back.height) == (640, 480)
        for attr in ("K", "dist", "R", "P"):
            np.testing.assert_array_equal(getattr(back, attr), getattr(cam, attr))


def _info(**fields):
    msg = model_to_camera_info(make_model())
    for k, v in fields.items():
        setattr(msg, k, v)
    return msg


def test_camera_info_defaults_for_unset_r_and_p():
    back = camera_info_to_model(_info(r=np.zeros(9), p=np.zeros(12)))
    np.testing.assert_array_equal(back.R, np.eye(3))
    np.testing.assert_array_equal(back.P, np.hstack([back.K, np.zeros((3, 1))]))
    four = camera_info_to_model(_info(d=[0.1, 0.2, 0.0, 0.0]))  # 4-coefficient plumb_bob
    np.testing.assert_array_equal(four.dist, [0.1, 0.2, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("fields,match", [
    ({"k": np.zeros(9)}, r"^k: the camera is uncalibrated"),
    ({"d": [0.1, 0.2, 0.3]}, r"^d: plumb_bob takes 5 coefficients, got 3"),
    ({"distortion_model": "equidistant"}, r"^distortion_model: 'equidistant' is not supported"),
    ({"width": 0}, r"^width/height"),
    ({"binning_x": 2}, r"^binning_x: binned"),
    ({"d": [0.1, float("nan"), 0.0, 0.0, 0.0]}, r"^d: contains NaN"),
    ({"r": np.diag([1.0, 1.0, -1.0])}, r"^camera_info: R: rectification matrix"),
])
def test_camera_info_errors_name_the_field(fields, match):
    with pytest.raises(ConversionError, match=match):
        camera_info_to_model(_info(**fields))


def test_camera_info_roi_is_refused():
    msg = _info()
    msg.roi.x_offset, msg.roi.width, msg.roi.height = 10, 100, 100
    with pytest.raises(ConversionError, match="^roi: a region of interest"):
        camera_info_to_model(msg)
    msg.roi.x_offset, msg.roi.width, msg.roi.height = 0, 640, 480
    assert camera_info_to_model(msg).width == 640


# -- poses, transforms, points, time ----------------------------------------------------------
def random_transforms(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    out = []
    for _ in range(n):
        axis = rng.normal(size=3)
        angle = rng.uniform(0.0, np.pi)
        out.append(from_rotvec(axis / np.linalg.norm(axis) * angle, rng.uniform(-2, 2, 3)))
    return out


def test_pose_transform_point_round_trips():
    from geometry_msgs.msg import PoseWithCovarianceStamped

    rng = np.random.default_rng(8)
    for T in random_transforms(rng, 20):
        ps = matrix_to_pose_stamped(T, stamp_ns=9, frame_id="base_link")
        assert ps.header.frame_id == "base_link" and ps.pose.orientation.w >= 0
        np.testing.assert_allclose(pose_to_matrix(ps), T, atol=1e-12)
        np.testing.assert_allclose(pose_to_matrix(ps.pose), T, atol=1e-12)
        cov = PoseWithCovarianceStamped()
        cov.pose.pose = ps.pose
        np.testing.assert_allclose(pose_to_matrix(cov), T, atol=1e-12)
        ts = matrix_to_transform_stamped(T, stamp_ns=9, frame_id="tool0",
                                              child_frame_id="camera_left_optical_frame")
        assert ts.child_frame_id == "camera_left_optical_frame"
        np.testing.assert_allclose(transform_to_matrix(ts), T, atol=1e-12)
        np.testing.assert_allclose(transform_to_matrix(ts.transform), T, atol=1e-12)
        p = xyz_to_point_stamped(T[:3, 3], stamp_ns=3, frame_id="cam")
        np.testing.assert_array_equal(point_to_xyz(p), T[:3, 3])
        np.testing.assert_array_equal(point_to_xyz(p.point), T[:3, 3])
        np.testing.assert_array_equal(point_to_xyz(ts.transform.translation), T[:3, 3])


def test_rosbags_pose_and_transform_messages(typestore):
    from rclpy.serialization import serialize_message

    rng = np.random.default_rng(9)
    T = random_transforms(rng, 1)[0]
    ps = matrix_to_pose_stamped(T, stamp_ns=1_234_000_000_005, frame_id="base_link")
    rb = typestore.deserialize_cdr(serialize_message(ps), "geometry_msgs/msg/PoseStamped")
    np.testing.assert_allclose(pose_to_matrix(rb), T, atol=1e-12)
    assert header_stamp_ns(rb) == 1_234_000_000_005
    ts = matrix_to_transform_stamped(T, frame_id="a", child_frame_id="b")
    rb = typestore.deserialize_cdr(serialize_message(ts), "geometry_msgs/msg/TransformStamped")
    np.testing.assert_allclose(transform_to_matrix(rb), T, atol=1e-12)
    pt = xyz_to_point_stamped([1.0, -2.0, 3.5])
    rb = typestore.deserialize_cdr(serialize_message(pt), "geometry_msgs/msg/PointStamped")
    np.testing.assert_array_equal(point_to_xyz(rb), [1.0, -2.0, 3.5])


def test_bad_poses_name_the_field():
    ps = matrix_to_pose_stamped(np.eye(4))
    ps.pose.position.y = float("nan")
    with pytest.raises(ConversionError, match=r"^pose\.position\.y: is nan"):
        pose_to_matrix(ps)
    ps = matrix_to_pose_stamped(np.eye(4))
    ps.pose.orientation.w = 0.0
    with pytest.raises(ConversionError, match=r"^pose\.orientation: quaternion has zero norm"):
        pose_to_matrix(ps)
    ps.pose.orientation.w = 2.0
    with pytest.raises(ConversionError, match=r"^pose\.orientation: quaternion norm is 2"):
        pose_to_matrix(ps)
    ts = matrix_to_transform_stamped(np.eye(4))
    ts.transform.translation.z = float("inf")
    with pytest.raises(ConversionError, match=r"^transform\.translation\.z: is inf"):
        transform_to_matrix(ts)
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(ConversionError, match="NaN"):
        matrix_to_pose(bad)
    with pytest.raises(ConversionError, match="not orthonormal"):
        matrix_to_pose(np.diag([1.0, 2.0, 1.0, 1.0]))
    with pytest.raises(ConversionError, match=r"^xyz: contains NaN"):
        xyz_to_point([0.0, np.nan, 1.0])
    with pytest.raises(ConversionError, match=r"^xyz: expected 3 values"):
        xyz_to_point([0.0, 1.0])


def test_time_conversions():
    for ns in (0, 1, 999_999_999, 1_000_000_000, 1_700_000_000_123_456_789, -1, -1_500_000_000):
        stamp = ns_to_stamp(ns)
        assert 0 <= stamp.nanosec < 10**9
        assert stamp_to_ns(stamp) == ns
    assert ns_to_stamp(np.int64(5)).nanosec == 5
    with pytest.raises(ConversionError, match="stamp_ns: expected int nanoseconds"):
        ns_to_stamp(1.0)
    with pytest.raises(ConversionError, match="does not fit"):
        ns_to_stamp(2**31 * 10**9)

    class Stamp:
        sec, nanosec = 1, 10**9

    with pytest.raises(ConversionError, match=r"^stamp\.nanosec: 1000000000 is outside"):
        stamp_to_ns(Stamp())
    header = make_header(1_000_000_007, "base_link")
    assert (header.stamp.sec, header.stamp.nanosec, header.frame_id) == (1, 7, "base_link")


def test_module_imports_and_decodes_without_rclpy_or_messages(tmp_path):
    """The msg -> numpy direction runs where rclpy and *_msgs are not installed."""
    script = r"""
import sys
import importlib.abc

BLOCKED = ("rclpy", "sensor_msgs", "geometry_msgs", "std_msgs", "builtin_interfaces",
           "diagnostic_msgs", "rcl_interfaces")

class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"blocked: {name}")
        return None

sys.meta_path.insert(0, Block())
import numpy as np
from eye_in_hand.ros.geometry import pose_to_matrix
from eye_in_hand.ros.images import image_to_numpy
from eye_in_hand.ros.stamps import header_stamp_ns
from rosbags.typesys import Stores, get_typestore

ts = get_typestore(Stores.ROS2_JAZZY)
T = ts.types
img = np.arange(24, dtype=np.uint8).reshape(2, 4, 3)
hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=3, nanosec=4),
                               frame_id="c")
msg = T["sensor_msgs/msg/Image"](header=hdr, height=2, width=4, encoding="rgb8",
                                 is_bigendian=0, step=12, data=img.reshape(-1))
out = image_to_numpy(msg, desired_encoding="bgr8")
assert (out == img[:, :, ::-1]).all()
pose = T["geometry_msgs/msg/Pose"](
    position=T["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=3.0),
    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
assert pose_to_matrix(pose)[0, 3] == 1.0
assert header_stamp_ns(msg) == 3_000_000_004
assert not any(m.split(".")[0] in BLOCKED for m in sys.modules)
print("ok")
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok"


def test_calibration_image_is_mono_bgr8_or_bgr16_whatever_came():
    rng = np.random.default_rng(3)
    bgr = rng.integers(0, 255, (6, 8, 3), dtype=np.uint8)
    rgb = numpy_to_image(np.ascontiguousarray(bgr[..., ::-1]), "rgb8")
    assert np.array_equal(calibration_image(rgb), bgr)
    wide = rng.integers(0, 65535, (6, 8, 3), dtype=np.uint16)
    rgb16 = numpy_to_image(np.ascontiguousarray(wide[..., ::-1]), "rgb16")
    got = calibration_image(rgb16)
    assert got.dtype == np.uint16 and np.array_equal(got, wide)
    for enc, dtype in (("mono8", np.uint8), ("mono16", np.uint16), ("16UC1", np.uint16)):
        grey = rng.integers(0, 200, (6, 8), dtype=dtype)
        assert np.array_equal(calibration_image(numpy_to_image(grey, enc)), grey)
    bgra = numpy_to_image(np.dstack([bgr, np.full((6, 8), 255, np.uint8)]), "bgra8")
    assert np.array_equal(calibration_image(bgra), bgr)
    png = numpy_to_compressed(bgr, "png")
    assert np.array_equal(calibration_image(png), bgr)


def test_pose_to_matrix_is_always_a_transform_the_pose_buffer_would_accept():
    """``PoseBuffer.add(checked=True)`` skips ``as_transform`` for ``pose_to_matrix``'s
    matrices: none of them, at the edges of what it accepts (quaternion norms 1 +- 1e-3,
    translations up to 1e300), may fail that check, else a checked pose would be one the
    buffer refuses unchecked."""
    from types import SimpleNamespace

    from eye_in_hand.core.transforms import as_transform

    rng = np.random.default_rng(11)
    for k in range(2000):
        q = rng.normal(size=4)
        q *= (1.0 + rng.uniform(-0.999e-3, 0.999e-3)) / np.linalg.norm(q)
        t = rng.normal(size=3) * 10.0 ** rng.integers(-300, 301, 3)
        msg = SimpleNamespace(
            position=SimpleNamespace(x=t[0], y=t[1], z=t[2]),
            orientation=SimpleNamespace(x=q[0], y=q[1], z=q[2], w=q[3]))
        T = pose_to_matrix(msg)
        assert T.dtype == np.float64 and T.shape == (4, 4)
        np.testing.assert_array_equal(as_transform(T, f"pose {k}"), T)


def _pose_values_cases():
    """(Pose-like message, its seven numbers) at random and at every check's edge."""
    from types import SimpleNamespace

    rng = np.random.default_rng(12)
    cases = []
    nan, inf = float("nan"), float("inf")
    for _ in range(400):
        q = rng.normal(size=4)
        q *= (1.0 + rng.uniform(-2e-3, 2e-3)) / np.linalg.norm(q)
        t = rng.normal(size=3) * 10.0 ** rng.integers(-300, 301, 3)
        cases.append((*t, *q))
    base = (0.4, -0.1, 0.5, 0.0, 0.0, 0.0, 1.0)
    for i in range(7):
        for bad in (nan, inf, -inf):
            cases.append(base[:i] + (bad,) + base[i + 1:])
    cases += [(0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 0.0), (0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 2.0),
              (nan, 0.2, 0.3, 0.0, 0.0, 0.0, 0.0), (0.1, 0.2, 0.3, 0.0, nan, 0.0, 2.0)]
    out = []
    for v in cases:
        v = tuple(float(a) for a in v)
        msg = SimpleNamespace(position=SimpleNamespace(x=v[0], y=v[1], z=v[2]),
                              orientation=SimpleNamespace(x=v[3], y=v[4], z=v[5], w=v[6]))
        out.append((msg, v))
    return out


def test_pose_values_to_matrix_is_pose_to_matrix_to_the_bit_and_error():
    """The robot pose read from CDR (``pose_values_to_matrix``) and from a message object
    (``pose_to_matrix``): the same matrix bit for bit, or the same first error."""
    from eye_in_hand.ros.geometry import pose_values_to_matrix

    n_errors = 0
    for msg, values in _pose_values_cases():
        try:
            ref = pose_to_matrix(msg)
        except ConversionError as exc:
            n_errors += 1
            with pytest.raises(ConversionError) as got:
                pose_values_to_matrix(values)
            assert str(got.value) == str(exc)
            continue
        T = pose_values_to_matrix(values)
        assert T.dtype == ref.dtype and T.tobytes() == ref.tobytes()
    assert n_errors > 21


def test_ee_pose_decoder_fields_from_any_encoding(typestore):
    """``ee_pose`` bytes from rclpy (little-endian CDR, read directly) and big-endian CDR (the
    generic decoder) give the fields of the message object; bad bytes raise."""
    from rclpy.serialization import serialize_message

    from eye_in_hand.nodes.hand_eye_poses import ee_pose_decoder
    from eye_in_hand.ros.geometry import pose_stamped_fields

    decode = ee_pose_decoder("geometry_msgs/msg/PoseStamped")
    T = from_rotvec([0.3, -0.2, 0.1], [0.4, -0.25, 0.6])
    for frame in ("", "b", "base_link", "/base"):
        msg = matrix_to_pose_stamped(T, stamp_ns=1_700_000_000_987_654_321, frame_id=frame)
        fields = decode(serialize_message(msg))
        assert fields == pose_stamped_fields(msg)
        assert fields[:3] == (1_700_000_000, 987_654_321, frame)
        rb = typestore.deserialize_cdr(serialize_message(msg), "geometry_msgs/msg/PoseStamped")
        big = bytes(typestore.serialize_cdr(rb, "geometry_msgs/msg/PoseStamped",
                                            little_endian=False))
        assert big[:2] == b"\x00\x00" and decode(big) == fields
    with pytest.raises(ConversionError):
        decode(serialize_message(msg)[:30])
    with pytest.raises(Exception):              # noqa: B017 - the generic decoder's own error
        decode(big[:30])
    with pytest.raises(ConversionError, match=r"^header: missing field"):
        pose_stamped_fields(make_header(0, "x"))


def test_detector_decoders_fields_from_any_encoding(typestore):
    """What ``hand_eye`` reads from a detector (``target/point``, ``*/point_cov``,
    ``targets/markers``): rclpy's bytes (little-endian CDR, read directly) and big-endian CDR
    (the generic decoder) give the fields of the message object; bad bytes raise."""
    from rclpy.serialization import serialize_message

    from eye_in_hand.nodes.hand_eye_first_target import (
        markers_decoder,
        point_cov_decoder,
        point_decoder,
    )
    from eye_in_hand.ros.geometry import point_stamped_fields, pose_cov_stamped_fields
    from eye_in_hand.ros.markers import marker_array_fields
    from eye_in_hand.ros.outputs import (
        Sphere,
        point_stamped,
        pose_with_covariance,
        rclpy_types,
        sphere_markers,
    )

    T = rclpy_types()
    cov = np.arange(9.0).reshape(3, 3) * 1e-6 + 1e-5
    for frame in ("", "c", "camera_left_optical_frame", "/cam"):
        xyz = (0.01, -0.02, 0.6 + len(frame))
        cases = [
            (point_decoder, "geometry_msgs/msg/PointStamped",
             point_stamped(T, xyz, 1_700_000_000_987_654_321, frame), point_stamped_fields),
            (point_cov_decoder, "geometry_msgs/msg/PoseWithCovarianceStamped",
             pose_with_covariance(T, xyz, cov, 5, frame), pose_cov_stamped_fields),
            (markers_decoder, "visualization_msgs/msg/MarkerArray", sphere_markers(
                T, [Sphere("red", xyz, 0.07, (1.0, 0.0, 0.0, 1.0)),
                    Sphere(f"g{frame}", xyz, 0.05, (0.0, 1.0, 0.25, 0.5))], 7, frame),
             marker_array_fields),
        ]
        for decoder_for, msgtype, msg, fields_of in cases:
            decode = decoder_for(msgtype)
            raw = serialize_message(msg)
            fields = decode(raw)
            assert fields == fields_of(msg)
            big = bytes(typestore.serialize_cdr(typestore.deserialize_cdr(raw, msgtype), msgtype,
                                                little_endian=False))
            assert big[:2] == b"\x00\x00" and decode(big) == fields
            with pytest.raises(ConversionError):
                decode(raw[:30])


def test_position_covariance_and_xyz_values():
    from eye_in_hand.ros.geometry import position_covariance, xyz_values

    values = tuple(np.random.default_rng(3).normal(size=36))
    block = position_covariance(values, "pose.covariance")
    assert block.dtype == np.float64 and block.flags.c_contiguous
    assert block.tobytes() == np.asarray(values).reshape(6, 6)[:3, :3].copy().tobytes()
    with pytest.raises(ConversionError, match=r"^pose.covariance: expected 36 numbers, got 35"):
        position_covariance(values[:35], "pose.covariance")
    assert xyz_values((1.0, -0.0, 2.5), "point").tolist() == [1.0, -0.0, 2.5]
    with pytest.raises(ConversionError, match=r"^point.y: is nan \(must be finite\)"):
        xyz_values((1.0, float("nan"), 2.5), "point")
    with pytest.raises(ConversionError, match=r"^point.z: expected a number"):
        xyz_values((1.0, 2.0, "x"), "point")
    with pytest.raises(ConversionError, match=r"^point: expected x, y, z, got 2"):
        xyz_values((1.0, 2.0), "point")
