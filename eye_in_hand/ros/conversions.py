"""Conversions between ROS messages and numpy arrays / core objects (our cv_bridge and tf glue).

Two directions, two rules:

* **message -> numpy** functions are *duck-typed*: they only read attributes, so they accept
  messages from rclpy (``data`` is an ``array.array``), messages deserialized by ``rosbags``
  (``data`` is a numpy ``uint8`` array) and anything shaped like them. They never import rclpy or
  message packages, so offline processing runs without ROS installed.
* **numpy -> message** functions build rclpy message objects and import the message classes
  inside the function.

Supported image encodings (``sensor_msgs/Image``): ``mono8``, ``mono16``, ``bgr8``, ``rgb8``,
``bgra8``, ``rgba8``, ``bgr16``, ``rgb16``, ``bgra16``, ``rgba16``, ``32FC1``, the 8-bit Bayer
mosaics ``bayer_rggb8``, ``bayer_bggr8``, ``bayer_gbrg8``, ``bayer_grbg8``, and the generic
aliases ``8UC1``, ``8UC3``, ``8UC4``, ``16UC1``. Row padding (``step`` larger than a row) and
``is_bigendian`` are honoured. Decoding is zero-copy whenever the layout allows it: the returned
array is a view of the message's buffer (read-only for ``bytes`` data); it is copied only when
byte swapping or a colour conversion is needed, or when asked with ``copy=True``.

``sensor_msgs/CompressedImage``: JPEG and PNG through ``cv2.imencode`` / ``cv2.imdecode``; the
``format`` string is written and read the way ``compressed_image_transport`` does
(``"bgr8; jpeg compressed bgr8"``), plain ``"jpeg"`` / ``"png"`` are read too.

Every malformed message raises :class:`eye_in_hand.errors.ConversionError` naming the field
(``data``, ``step``, ``encoding``, ``pose.orientation``, ``k``, ...).
"""
from __future__ import annotations

import array
import math
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from eye_in_hand.errors import ConversionError, InputError

__all__ = [
    "IMAGE_ENCODINGS",
    "COMPRESSED_FORMATS",
    "stamp_to_ns",
    "ns_to_stamp",
    "header_stamp_ns",
    "make_header",
    "image_to_numpy",
    "numpy_to_image",
    "convert_encoding",
    "compressed_to_numpy",
    "numpy_to_compressed",
    "camera_info_to_model",
    "model_to_camera_info",
    "pose_to_matrix",
    "matrix_to_pose",
    "matrix_to_pose_stamped",
    "transform_to_matrix",
    "matrix_to_transform",
    "matrix_to_transform_stamped",
    "point_to_xyz",
    "xyz_to_point",
    "xyz_to_point_stamped",
]

_NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def _get(msg: Any, attr: str, path: str) -> Any:
    try:
        return getattr(msg, attr)
    except AttributeError as exc:
        where = f"{path}.{attr}" if path else attr
        raise ConversionError(
            f"{where}: missing field (got a {type(msg).__name__})") from exc


def _field(path: str, attr: str) -> str:
    return f"{path}.{attr}" if path else attr


def _read_int(msg: Any, attr: str, path: str = "") -> int:
    value = _get(msg, attr, path)
    try:
        if isinstance(value, (bool, np.bool_)) or int(value) != value:
            raise TypeError
        return int(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ConversionError(
            f"{_field(path, attr)}: expected an integer, got {value!r}") from exc


def _read_float(msg: Any, attr: str, path: str = "") -> float:
    value = _get(msg, attr, path)
    try:
        out = float(value)
    except (TypeError, ValueError) as exc:
        raise ConversionError(f"{_field(path, attr)}: expected a number, got {value!r}") from exc
    if not math.isfinite(out):
        raise ConversionError(f"{_field(path, attr)}: is {out} (must be finite)")
    return out


def _read_str(msg: Any, attr: str, path: str = "") -> str:
    value = _get(msg, attr, path)
    if not isinstance(value, str):
        raise ConversionError(f"{_field(path, attr)}: expected a string, got {value!r}")
    return value


def _byte_view(data: Any, field: str) -> np.ndarray:
    """A 1-D uint8 view of a message's ``uint8[]`` field, without copying when possible.

    Handles ``array.array('B')`` (rclpy), numpy ``uint8`` arrays (rosbags), ``bytes``,
    ``bytearray`` and ``memoryview``; anything else (e.g. a list of ints) is copied.
    """
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8:
            raise ConversionError(f"{field}: expected uint8 data, got dtype {data.dtype}")
        return data.reshape(-1)  # a view for contiguous data (always, for rosbags messages)
    if isinstance(data, (array.array, bytes, bytearray, memoryview)):
        if isinstance(data, array.array) and data.itemsize != 1:
            raise ConversionError(f"{field}: expected a byte array, got typecode {data.typecode!r}")
        try:
            return np.frombuffer(data, dtype=np.uint8)
        except (TypeError, ValueError) as exc:
            raise ConversionError(f"{field}: cannot be read as bytes") from exc
    try:
        arr = np.asarray(data)
    except (TypeError, ValueError) as exc:
        raise ConversionError(f"{field}: cannot be read as bytes ({type(data).__name__})") from exc
    if arr.ndim != 1 or (arr.size and (arr.dtype.kind not in "iu" or arr.min() < 0
                                       or arr.max() > 255)):
        raise ConversionError(f"{field}: expected a sequence of bytes (0..255)")
    return arr.astype(np.uint8)


def _to_byte_array(arr: np.ndarray) -> array.array:
    """Copy a C-contiguous array's bytes into the ``array.array('B')`` rclpy stores (one copy)."""
    out = array.array("B")
    out.frombytes(np.ascontiguousarray(arr).data.cast("B"))
    return out


# ----------------------------------------------------------------------------------------------
# time and header
# ----------------------------------------------------------------------------------------------
def stamp_to_ns(stamp: Any, *, field: str = "stamp") -> int:
    """Nanoseconds (int) of a ``builtin_interfaces/Time``-like object (``sec``, ``nanosec``).

    Raises:
        ConversionError: missing fields, or ``nanosec`` outside [0, 1e9).
    """
    sec = _read_int(stamp, "sec", field)
    nanosec = _read_int(stamp, "nanosec", field)
    if not 0 <= nanosec < _NS_PER_S:
        raise ConversionError(f"{field}.nanosec: {nanosec} is outside [0, 1e9)")
    return sec * _NS_PER_S + nanosec


def ns_to_stamp(stamp_ns: int) -> Any:
    """A ``builtin_interfaces.msg.Time`` from int nanoseconds (negative stamps are floored).

    Raises:
        ConversionError: not an integer, or seconds outside the int32 range of the message.
    """
    from builtin_interfaces.msg import Time

    if isinstance(stamp_ns, (bool, np.bool_)) or not isinstance(stamp_ns, (int, np.integer)):
        raise ConversionError(
            f"stamp_ns: expected int nanoseconds, got {type(stamp_ns).__name__} {stamp_ns!r}")
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise ConversionError(f"stamp_ns: {stamp_ns} does not fit builtin_interfaces/Time")
    return Time(sec=sec, nanosec=nanosec)


def header_stamp_ns(msg: Any) -> int:
    """Nanoseconds of ``msg.header.stamp`` (any stamped message, rclpy or rosbags)."""
    return stamp_to_ns(_get(_get(msg, "header", ""), "stamp", "header"), field="header.stamp")


def make_header(stamp_ns: int = 0, frame_id: str = "") -> Any:
    """A ``std_msgs.msg.Header`` with the given stamp (int ns) and frame id."""
    from std_msgs.msg import Header

    if not isinstance(frame_id, str):
        raise ConversionError(f"frame_id: expected a string, got {frame_id!r}")
    return Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)


def _header(header: Any, stamp_ns: int, frame_id: str) -> Any:
    return make_header(stamp_ns, frame_id) if header is None else header


# ----------------------------------------------------------------------------------------------
# images
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Encoding:
    dtype: np.dtype
    channels: int
    family: str  # 'colour' (convertible by cv2), 'bayer', or 'generic' (no channel semantics)


def _enc(dtype: Any, channels: int, family: str) -> _Encoding:
    return _Encoding(np.dtype(dtype), channels, family)


#: Supported ``sensor_msgs/Image`` encodings -> (dtype, channels, family).
IMAGE_ENCODINGS: dict[str, _Encoding] = {
    "mono8": _enc(np.uint8, 1, "colour"),
    "bgr8": _enc(np.uint8, 3, "colour"),
    "rgb8": _enc(np.uint8, 3, "colour"),
    "bgra8": _enc(np.uint8, 4, "colour"),
    "rgba8": _enc(np.uint8, 4, "colour"),
    "mono16": _enc(np.uint16, 1, "colour16"),
    "bgr16": _enc(np.uint16, 3, "colour16"),
    "rgb16": _enc(np.uint16, 3, "colour16"),
    "bgra16": _enc(np.uint16, 4, "colour16"),
    "rgba16": _enc(np.uint16, 4, "colour16"),
    "bayer_rggb8": _enc(np.uint8, 1, "bayer"),
    "bayer_bggr8": _enc(np.uint8, 1, "bayer"),
    "bayer_gbrg8": _enc(np.uint8, 1, "bayer"),
    "bayer_grbg8": _enc(np.uint8, 1, "bayer"),
    "8UC1": _enc(np.uint8, 1, "generic"),
    "8UC3": _enc(np.uint8, 3, "generic"),
    "8UC4": _enc(np.uint8, 4, "generic"),
    "16UC1": _enc(np.uint16, 1, "generic"),
    "32FC1": _enc(np.float32, 1, "generic"),
}

# Channel layouts of the convertible encodings (8-bit and 16-bit share them).
_LAYOUT = {"mono": "GRAY", "bgr": "BGR", "rgb": "RGB", "bgra": "BGRA", "rgba": "RGBA"}
_BAYER_CV = {"bayer_rggb8": "RGGB", "bayer_bggr8": "BGGR",
             "bayer_gbrg8": "GBRG", "bayer_grbg8": "GRBG"}


def _encoding_spec(encoding: str, field: str = "encoding") -> _Encoding:
    spec = IMAGE_ENCODINGS.get(encoding)
    if spec is None:
        raise ConversionError(
            f"{field}: unsupported image encoding {encoding!r} "
            f"(supported: {', '.join(IMAGE_ENCODINGS)})")
    return spec


def _layout(encoding: str) -> str:
    return _LAYOUT[encoding.rstrip("0123456789")]


def convert_encoding(image: np.ndarray, src: str, dst: str) -> np.ndarray:
    """Convert an image between encodings (channel order, mono/colour, Bayer demosaicing).

    Conversions exist between ``mono8``/``bgr8``/``rgb8``/``bgra8``/``rgba8``, between the 16-bit
    counterparts, and from the 8-bit Bayer mosaics to the 8-bit colour encodings. A generic
    alias (``8UC3`` ...) converts only to an encoding with the same dtype and channel count
    (a relabelling, no copy). The bit depth is never changed.

    Args:
        image: array of shape (H, W) or (H, W, C) laid out as ``src``.
        src: the encoding of ``image``.
        dst: the wanted encoding.

    Returns:
        ``image`` itself when nothing changes, else a new array laid out as ``dst``.

    Raises:
        ConversionError: unknown encoding, or no conversion between the two.
    """
    import cv2

    s = _encoding_spec(src, "encoding")
    d = _encoding_spec(dst, "desired_encoding")
    if src == dst:
        return image
    if (s.family == "generic" or d.family == "generic") and (s.dtype, s.channels) == (
            d.dtype, d.channels):
        return image
    if s.dtype != d.dtype:
        raise ConversionError(
            f"desired_encoding: no conversion from {src} to {dst} (bit depth would change)")
    if s.family == "bayer" and d.family == "colour" and d.channels in (1, 3, 4):
        name = f"COLOR_Bayer{_BAYER_CV[src]}2{_layout(dst)}"
    elif s.family == d.family and s.family in ("colour", "colour16"):
        name = f"COLOR_{_layout(src)}2{_layout(dst)}"
    else:
        name = ""
    code = getattr(cv2, name, None) if name else None
    if code is None:
        raise ConversionError(f"desired_encoding: no conversion from {src} to {dst}")
    return cv2.cvtColor(image, code)


def image_to_numpy(msg: Any, *, desired_encoding: str | None = None,
                   copy: bool = False) -> np.ndarray:
    """Decode a ``sensor_msgs/Image`` (rclpy or rosbags) into a numpy array.

    Args:
        msg: object with ``height``, ``width``, ``encoding``, ``is_bigendian``, ``step``, ``data``.
        desired_encoding: ``None`` or ``"passthrough"`` to keep the message's layout, else an
            encoding to convert to (see :func:`convert_encoding`).
        copy: return an array that owns its memory even when a view would do.

    Returns:
        shape (H, W) for one channel, (H, W, C) otherwise; dtype ``uint8``, ``uint16`` or
        ``float32`` in native byte order. Unless copied, a view of ``msg.data`` (writes to it
        change the message; for ``bytes`` data it is read-only).

    Raises:
        ConversionError: unknown encoding, ``step`` shorter than a row, ``data`` length not equal
            to ``height * step``, empty image, or an impossible conversion.
    """
    encoding = _read_str(msg, "encoding")
    spec = _encoding_spec(encoding)
    height = _read_int(msg, "height")
    width = _read_int(msg, "width")
    step = _read_int(msg, "step")
    bigendian = _read_int(msg, "is_bigendian")
    if height <= 0 or width <= 0:
        raise ConversionError(f"height/width: empty or negative image size {width}x{height}")
    row_bytes = width * spec.channels * spec.dtype.itemsize
    if step < row_bytes:
        raise ConversionError(
            f"step: {step} is shorter than a row of {width} {encoding} pixels ({row_bytes} bytes)")
    buf = _byte_view(_get(msg, "data", ""), "data")
    if buf.size != height * step:
        raise ConversionError(
            f"data: length {buf.size} does not match height * step = {height} * {step} "
            f"= {height * step}")
    rows = buf.reshape(height, step)
    if step != row_bytes:
        rows = rows[:, :row_bytes]  # drop row padding: still a view
    dtype = spec.dtype
    if dtype.itemsize > 1:
        dtype = dtype.newbyteorder(">" if bigendian else "<")
    arr = rows.view(dtype)  # the last axis is contiguous, so this is a view even with padding
    arr = arr.reshape((height, width) if spec.channels == 1 else (height, width, spec.channels))
    if not arr.dtype.isnative:
        arr = arr.astype(arr.dtype.newbyteorder("="))  # a copy already
        copy = False
    if desired_encoding not in (None, "passthrough", encoding):
        converted = convert_encoding(arr, encoding, desired_encoding)
        copy = copy and np.shares_memory(converted, arr)  # relabelled aliases share memory
        arr = converted
    return arr.copy() if copy else arr


def _infer_encoding(arr: np.ndarray) -> str:
    channels = 1 if arr.ndim == 2 else arr.shape[2] if arr.ndim == 3 else 0
    table = {(np.dtype(np.uint8), 1): "mono8", (np.dtype(np.uint8), 3): "bgr8",
             (np.dtype(np.uint8), 4): "bgra8", (np.dtype(np.uint16), 1): "mono16",
             (np.dtype(np.uint16), 3): "bgr16", (np.dtype(np.uint16), 4): "bgra16",
             (np.dtype(np.float32), 1): "32FC1"}
    enc = table.get((arr.dtype.newbyteorder("="), channels))
    if enc is None:
        raise ConversionError(
            f"image: cannot infer an encoding for shape {arr.shape} dtype {arr.dtype}; "
            "pass encoding=")
    return enc


def _check_image_array(image: Any, encoding: str | None) -> tuple[np.ndarray, str, _Encoding]:
    arr = np.asarray(image)
    if encoding is None:
        encoding = _infer_encoding(arr)
    spec = _encoding_spec(encoding)
    if arr.dtype.newbyteorder("=") != spec.dtype:
        raise ConversionError(
            f"image: dtype {arr.dtype} does not match encoding {encoding} ({spec.dtype})")
    if spec.channels == 1 and arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    expected = 2 if spec.channels == 1 else 3
    if arr.ndim != expected or (expected == 3 and arr.shape[2] != spec.channels) \
            or arr.shape[0] == 0 or arr.shape[1] == 0:
        want = "(H, W)" if spec.channels == 1 else f"(H, W, {spec.channels})"
        raise ConversionError(
            f"image: shape {arr.shape} does not match encoding {encoding}, expected {want}")
    if not arr.dtype.isnative:
        arr = arr.astype(arr.dtype.newbyteorder("="))
    return arr, encoding, spec


def numpy_to_image(image: Any, encoding: str | None = None, *, stamp_ns: int = 0,
                   frame_id: str = "", header: Any = None) -> Any:
    """Build a ``sensor_msgs.msg.Image`` from an array (one copy of the pixels).

    Args:
        image: shape (H, W) or (H, W, C). dtype must match the encoding.
        encoding: one of :data:`IMAGE_ENCODINGS`; inferred when ``None`` (uint8: mono8, bgr8,
            bgra8; uint16: mono16, bgr16, bgra16; float32: 32FC1).
        stamp_ns: header stamp in int nanoseconds (ignored when ``header`` is given).
        frame_id: header frame id (ignored when ``header`` is given).
        header: a ready ``std_msgs/Header`` to use as is.

    Returns:
        The message, rows unpadded (``step = W * C * itemsize``), native byte order.

    Raises:
        ConversionError: unknown encoding, or shape/dtype not matching it.
    """
    from sensor_msgs.msg import Image

    arr, encoding, spec = _check_image_array(image, encoding)
    msg = Image()
    msg.header = _header(header, stamp_ns, frame_id)
    msg.height = int(arr.shape[0])
    msg.width = int(arr.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = int(sys.byteorder == "big" and spec.dtype.itemsize > 1)
    msg.step = int(arr.shape[1] * spec.channels * spec.dtype.itemsize)
    msg.data = _to_byte_array(arr)
    return msg


# ----------------------------------------------------------------------------------------------
# compressed images
# ----------------------------------------------------------------------------------------------
#: Compression formats accepted by :func:`numpy_to_compressed`.
COMPRESSED_FORMATS: tuple[str, ...] = ("jpeg", "png")


def _parse_compressed_format(fmt: str) -> tuple[str | None, str | None]:
    """(original encoding or None, 'jpeg' | 'png' | None when unspecified)."""
    original: str | None = None
    rest = fmt
    if ";" in fmt:
        head, rest = fmt.split(";", 1)
        original = head.strip() or None
    tokens = rest.lower().replace(",", " ").split()
    kinds = {"jpeg": "jpeg", "jpg": "jpeg", "png": "png"}
    found = [kinds[t] for t in tokens if t in kinds]
    if not found:
        if tokens:
            raise ConversionError(
                f"format: unsupported compressed image format {fmt!r} (supported: jpeg, png)")
        return original, None
    return original, found[0]


def compressed_to_numpy(msg: Any, *, desired_encoding: str | None = None) -> np.ndarray:
    """Decode a ``sensor_msgs/CompressedImage`` (JPEG or PNG; rclpy or rosbags).

    Without ``desired_encoding`` the result is laid out as the encoding named in front of the
    ``format`` string (``"rgb8; jpeg compressed bgr8"`` gives rgb8), as
    ``compressed_image_transport`` does, else as OpenCV decodes it (mono8, bgr8, bgra8, mono16,
    bgr16 ...).

    Args:
        msg: object with ``format`` and ``data``.
        desired_encoding: ``None``/``"passthrough"`` or an encoding to convert to.

    Returns:
        shape (H, W) or (H, W, C), dtype uint8 or uint16.

    Raises:
        ConversionError: unsupported ``format``, undecodable ``data``, impossible conversion.
    """
    import cv2

    fmt = _read_str(msg, "format")
    original, kind = _parse_compressed_format(fmt)
    buf = _byte_view(_get(msg, "data", ""), "data")
    if buf.size == 0:
        raise ConversionError("data: empty compressed image")
    image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ConversionError(
            f"data: {buf.size} bytes could not be decoded as {kind or 'an image'} "
            f"(format {fmt!r})")
    decoded = _infer_encoding(image)
    if desired_encoding not in (None, "passthrough"):
        return convert_encoding(image, decoded, desired_encoding)
    spec = IMAGE_ENCODINGS.get(original or "")
    if original is None or spec is None or original == decoded or spec.dtype != image.dtype:
        return image  # no (usable) original encoding recorded: keep OpenCV's layout
    if spec.family in ("bayer", "generic") and spec.channels == IMAGE_ENCODINGS[decoded].channels:
        return image  # a raw mosaic or a generic layout, stored as decoded
    return convert_encoding(image, decoded, original)


def numpy_to_compressed(image: Any, format: str = "jpeg", *, encoding: str | None = None,
                        jpeg_quality: int = 95, png_level: int = 3, stamp_ns: int = 0,
                        frame_id: str = "", header: Any = None) -> Any:
    """Build a ``sensor_msgs.msg.CompressedImage`` (JPEG or PNG).

    Colour images are stored in BGR channel order as OpenCV (and image_transport) expects; the
    ``format`` string records the original encoding: ``"<encoding>; jpeg compressed bgr8"``.

    Args:
        image: shape (H, W) or (H, W, C). JPEG takes 8-bit mono or 3-channel images; PNG also
            takes 4-channel and 16-bit images.
        format: ``"jpeg"`` or ``"png"``.
        encoding: the layout of ``image`` (inferred when ``None``, see :func:`numpy_to_image`).
        jpeg_quality: 0..100.
        png_level: PNG compression level 0..9.
        stamp_ns, frame_id, header: as in :func:`numpy_to_image`.

    Raises:
        ConversionError: unsupported format or image layout, or encoding failure.
    """
    import cv2
    from sensor_msgs.msg import CompressedImage

    kind = {"jpeg": "jpeg", "jpg": "jpeg", "png": "png"}.get(str(format).lower())
    if kind is None:
        raise ConversionError(f"format: unsupported compressed format {format!r} (jpeg, png)")
    if not 0 <= int(jpeg_quality) <= 100:
        raise ConversionError(f"jpeg_quality: {jpeg_quality} is outside [0, 100]")
    if not 0 <= int(png_level) <= 9:
        raise ConversionError(f"png_level: {png_level} is outside [0, 9]")
    arr, encoding, spec = _check_image_array(image, encoding)
    if spec.family == "generic" or spec.dtype == np.float32:
        raise ConversionError(f"encoding: {encoding} has no colour layout to compress")
    if spec.family == "bayer":
        stored = "mono8"  # the raw mosaic, as a grey image; the format keeps its encoding
    else:
        depth = "8" if spec.dtype == np.uint8 else "16"
        stored = {1: "mono", 3: "bgr", 4: "bgra"}[spec.channels] + depth
        arr = convert_encoding(arr, encoding, stored)
    if kind == "jpeg" and (arr.dtype != np.uint8 or spec.channels == 4):
        raise ConversionError(
            f"image: JPEG takes 8-bit mono or 3-channel images, not {encoding}; use png")
    params = ([cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if kind == "jpeg"
              else [cv2.IMWRITE_PNG_COMPRESSION, int(png_level)])
    ok, buf = cv2.imencode(".jpg" if kind == "jpeg" else ".png", arr, params)
    if not ok:
        raise ConversionError(f"image: OpenCV could not encode a {encoding} image as {kind}")
    msg = CompressedImage()
    msg.header = _header(header, stamp_ns, frame_id)
    msg.format = f"{encoding}; {kind} compressed {stored}"
    msg.data = _to_byte_array(buf.reshape(-1))
    return msg


# ----------------------------------------------------------------------------------------------
# camera info
# ----------------------------------------------------------------------------------------------
def _read_floats(msg: Any, attr: str, size: int | None) -> np.ndarray:
    value = _get(msg, attr, "")
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ConversionError(f"{attr}: expected numbers, got {value!r}") from exc
    if size is not None and arr.size != size:
        raise ConversionError(f"{attr}: expected {size} values, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ConversionError(f"{attr}: contains NaN or infinite values")
    return arr


def camera_info_to_model(msg: Any, *, name: str = "camera") -> Any:
    """A :class:`eye_in_hand.core.camera.CameraModel` from a ``sensor_msgs/CameraInfo``.

    An all-zero ``r`` (not set by the driver) is read as identity and an all-zero ``p`` as
    ``[K | 0]``. ``binning_x/y`` > 1 and a region of interest smaller than the image are
    refused, since the model has no place for them.

    Args:
        msg: object with ``width``, ``height``, ``distortion_model``, ``d``, ``k``, ``r``, ``p``
            (and optionally ``binning_x``, ``binning_y``, ``roi``).
        name: camera name of the model.

    Returns:
        The camera model.

    Raises:
        ConversionError: uncalibrated camera (``k`` all zero), unsupported ``distortion_model``,
            wrong ``d`` length, bad ``k``/``r``/``p``, size or binning.
    """
    from eye_in_hand.core.camera import DISTORTION_MODELS, CameraModel

    width = _read_int(msg, "width")
    height = _read_int(msg, "height")
    if width <= 0 or height <= 0:
        raise ConversionError(f"width/height: image size must be positive, got {width}x{height}")
    model = _read_str(msg, "distortion_model")
    if model not in DISTORTION_MODELS:
        raise ConversionError(
            f"distortion_model: {model!r} is not supported "
            f"(supported: {', '.join(DISTORTION_MODELS)})")
    d = _read_floats(msg, "d", None)
    n = DISTORTION_MODELS[model]
    if d.size not in (n, 4 if model == "plumb_bob" else n):
        raise ConversionError(f"d: {model} takes {n} coefficients, got {d.size}")
    K = _read_floats(msg, "k", 9).reshape(3, 3)
    if K[0, 0] == 0.0:
        raise ConversionError("k: the camera is uncalibrated (k[0] == 0)")
    R = _read_floats(msg, "r", 9).reshape(3, 3)
    if not np.any(R):
        R = np.eye(3)
    P = _read_floats(msg, "p", 12).reshape(3, 4)
    for axis in ("binning_x", "binning_y"):
        if hasattr(msg, axis) and _read_int(msg, axis) > 1:
            raise ConversionError(f"{axis}: binned camera_info is not supported")
    roi = getattr(msg, "roi", None)
    if roi is not None:
        rw, rh = _read_int(roi, "width", "roi"), _read_int(roi, "height", "roi")
        rx, ry = _read_int(roi, "x_offset", "roi"), _read_int(roi, "y_offset", "roi")
        if (rw, rh) != (0, 0) and (rx, ry, rw, rh) != (0, 0, width, height):
            raise ConversionError(
                f"roi: a region of interest ({rx}, {ry}, {rw}x{rh}) is not supported")
    try:
        return CameraModel(K=K, dist=d, width=width, height=height, distortion_model=model,
                           R=R, P=P if np.any(P) else None, name=name)
    except InputError as exc:
        raise ConversionError(f"camera_info: {exc}") from exc


def model_to_camera_info(model: Any, *, stamp_ns: int = 0, frame_id: str = "",
                         header: Any = None) -> Any:
    """A ``sensor_msgs.msg.CameraInfo`` from a camera model (binning 1, full-image roi).

    Args:
        model: a :class:`eye_in_hand.core.camera.CameraModel`.
        stamp_ns, frame_id, header: as in :func:`numpy_to_image`.
    """
    from sensor_msgs.msg import CameraInfo

    msg = CameraInfo()
    msg.header = _header(header, stamp_ns, frame_id)
    msg.width = int(model.width)
    msg.height = int(model.height)
    msg.distortion_model = str(model.distortion_model)
    msg.d = [float(v) for v in np.asarray(model.dist, dtype=np.float64).ravel()]
    msg.k = np.asarray(model.K, dtype=np.float64).reshape(9)
    msg.r = np.asarray(model.R, dtype=np.float64).reshape(9)
    msg.p = np.asarray(model.P, dtype=np.float64).reshape(12)
    msg.binning_x = 0
    msg.binning_y = 0
    return msg


# ----------------------------------------------------------------------------------------------
# poses, transforms, points
# ----------------------------------------------------------------------------------------------
def _xyz(obj: Any, path: str) -> np.ndarray:
    return np.array([_read_float(obj, a, path) for a in ("x", "y", "z")])


def _quat_matrix(obj: Any, path: str) -> np.ndarray:
    from eye_in_hand.core.transforms import quat_xyzw_to_matrix

    q = np.array([_read_float(obj, a, path) for a in ("x", "y", "z", "w")])
    try:
        return quat_xyzw_to_matrix(q, path)
    except InputError as exc:
        raise ConversionError(str(exc)) from exc


def _checked_transform(T: Any, name: str) -> np.ndarray:
    from eye_in_hand.core.transforms import as_transform

    try:
        return as_transform(T, name)
    except InputError as exc:
        raise ConversionError(str(exc)) from exc


def pose_to_matrix(msg: Any) -> np.ndarray:
    """4x4 transform of a ``Pose``, ``PoseStamped``, ``PoseWithCovariance(Stamped)``.

    For a pose of frame ``b`` given in frame ``a`` (``header.frame_id``) this is ``a_T_b``.

    Raises:
        ConversionError: missing or non-finite fields, zero or far-from-unit quaternion
            (the message names the field, e.g. ``pose.orientation``).
    """
    path = ""
    while hasattr(msg, "pose"):
        msg = msg.pose
        path = _field(path, "pose")
    T = np.eye(4)
    T[:3, :3] = _quat_matrix(_get(msg, "orientation", path), _field(path, "orientation"))
    T[:3, 3] = _xyz(_get(msg, "position", path), _field(path, "position"))
    return T


def transform_to_matrix(msg: Any) -> np.ndarray:
    """4x4 transform of a ``Transform`` or ``TransformStamped``.

    A ``TransformStamped`` with ``header.frame_id = a`` and ``child_frame_id = b`` gives ``a_T_b``.

    Raises:
        ConversionError: missing or non-finite fields, bad quaternion (naming the field).
    """
    path = ""
    if hasattr(msg, "transform"):
        msg = msg.transform
        path = "transform"
    T = np.eye(4)
    T[:3, :3] = _quat_matrix(_get(msg, "rotation", path), _field(path, "rotation"))
    T[:3, 3] = _xyz(_get(msg, "translation", path), _field(path, "translation"))
    return T


def point_to_xyz(msg: Any) -> np.ndarray:
    """(3,) float64 of a ``Point``, ``PointStamped``, ``Point32`` or ``Vector3``.

    Raises:
        ConversionError: missing or non-finite coordinates (naming the field).
    """
    path = ""
    if hasattr(msg, "point"):
        msg = msg.point
        path = "point"
    return _xyz(msg, path)


def matrix_to_pose(T: Any) -> Any:
    """A ``geometry_msgs.msg.Pose`` from a 4x4 transform (quaternion with w >= 0).

    Raises:
        ConversionError: not a finite rigid transform.
    """
    from geometry_msgs.msg import Point, Pose, Quaternion

    from eye_in_hand.core.transforms import matrix_to_quat_xyzw

    arr = _checked_transform(T, "T")
    q = matrix_to_quat_xyzw(arr[:3, :3])
    t = arr[:3, 3]
    return Pose(position=Point(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                orientation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                       w=float(q[3])))


def matrix_to_pose_stamped(T: Any, *, stamp_ns: int = 0, frame_id: str = "",
                           header: Any = None) -> Any:
    """A ``geometry_msgs.msg.PoseStamped`` from ``frame_id_T_pose`` (4x4)."""
    from geometry_msgs.msg import PoseStamped

    pose = matrix_to_pose(T)
    return PoseStamped(header=_header(header, stamp_ns, frame_id), pose=pose)


def matrix_to_transform(T: Any) -> Any:
    """A ``geometry_msgs.msg.Transform`` from a 4x4 transform."""
    from geometry_msgs.msg import Quaternion, Transform, Vector3

    pose = matrix_to_pose(T)
    p, q = pose.position, pose.orientation
    return Transform(translation=Vector3(x=p.x, y=p.y, z=p.z),
                     rotation=Quaternion(x=q.x, y=q.y, z=q.z, w=q.w))


def matrix_to_transform_stamped(T: Any, *, stamp_ns: int = 0, frame_id: str = "",
                                child_frame_id: str = "", header: Any = None) -> Any:
    """A ``geometry_msgs.msg.TransformStamped`` from ``frame_id_T_child_frame_id`` (4x4)."""
    from geometry_msgs.msg import TransformStamped

    if not isinstance(child_frame_id, str):
        raise ConversionError(f"child_frame_id: expected a string, got {child_frame_id!r}")
    return TransformStamped(header=_header(header, stamp_ns, frame_id),
                            child_frame_id=child_frame_id, transform=matrix_to_transform(T))


def _checked_xyz(xyz: Any) -> np.ndarray:
    try:
        arr = np.asarray(xyz, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ConversionError(f"xyz: expected 3 numbers, got {xyz!r}") from exc
    if arr.shape != (3,):
        raise ConversionError(f"xyz: expected 3 values, got shape {np.shape(xyz)}")
    if not np.all(np.isfinite(arr)):
        raise ConversionError(f"xyz: contains NaN or infinite values: {arr.tolist()}")
    return arr


def xyz_to_point(xyz: Any) -> Any:
    """A ``geometry_msgs.msg.Point`` from array-like shape (3,)."""
    from geometry_msgs.msg import Point

    v = _checked_xyz(xyz)
    return Point(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def xyz_to_point_stamped(xyz: Any, *, stamp_ns: int = 0, frame_id: str = "",
                         header: Any = None) -> Any:
    """A ``geometry_msgs.msg.PointStamped`` from array-like shape (3,)."""
    from geometry_msgs.msg import PointStamped

    return PointStamped(header=_header(header, stamp_ns, frame_id), point=xyz_to_point(xyz))
