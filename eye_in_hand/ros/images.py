"""Images: ``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` <-> numpy (our cv_bridge).

Decoders are duck-typed: they accept messages from rclpy (``data`` is an ``array.array``), from
``rosbags`` (``data`` is a numpy ``uint8`` array) and anything shaped like them, and never import
message packages. Encoders build rclpy message objects.

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

Every malformed message raises :class:`eye_in_hand.errors.ConversionError` naming the field.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from eye_in_hand.errors import ConversionError
from eye_in_hand.ros.fields import byte_view, get_field, read_int, read_str, to_byte_array
from eye_in_hand.ros.stamps import header_or_new

__all__ = [
    "IMAGE_ENCODINGS",
    "COMPRESSED_FORMATS",
    "image_to_numpy",
    "numpy_to_image",
    "convert_encoding",
    "compressed_to_numpy",
    "numpy_to_compressed",
    "calibration_image",
]


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
    encoding = read_str(msg, "encoding")
    spec = _encoding_spec(encoding)
    height = read_int(msg, "height")
    width = read_int(msg, "width")
    step = read_int(msg, "step")
    bigendian = read_int(msg, "is_bigendian")
    if height <= 0 or width <= 0:
        raise ConversionError(f"height/width: empty or negative image size {width}x{height}")
    row_bytes = width * spec.channels * spec.dtype.itemsize
    if step < row_bytes:
        raise ConversionError(
            f"step: {step} is shorter than a row of {width} {encoding} pixels ({row_bytes} bytes)")
    buf = byte_view(get_field(msg, "data", ""), "data")
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
    # the last axis is contiguous, so this is a view even with padding
    arr: np.ndarray = rows.view(dtype)
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
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from sensor_msgs.msg import Image

    arr, encoding, spec = _check_image_array(image, encoding)
    msg = Image()
    msg.header = header_or_new(header, stamp_ns, frame_id)
    msg.height = int(arr.shape[0])
    msg.width = int(arr.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = int(sys.byteorder == "big" and spec.dtype.itemsize > 1)
    msg.step = int(arr.shape[1] * spec.channels * spec.dtype.itemsize)
    msg.data = to_byte_array(arr)
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
    fmt = read_str(msg, "format")
    original, kind = _parse_compressed_format(fmt)
    buf = byte_view(get_field(msg, "data", ""), "data")
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
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
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
    msg.header = header_or_new(header, stamp_ns, frame_id)
    msg.format = f"{encoding}; {kind} compressed {stored}"
    msg.data = to_byte_array(buf.reshape(-1))
    return msg



def calibration_image(msg: Any) -> np.ndarray:
    """A calibration image as board detection takes it, from an ``Image`` or a
    ``CompressedImage`` (rclpy or rosbags): a mono image (``mono8``, ``mono16``, ``8UC1``,
    ``16UC1``) as it is, a colour one as ``bgr16`` if 16-bit, else ``bgr8``; a copy that owns
    its pixels. The one rule of ``calibrate camera|stereo|handeye`` from a bag, of their bag
    samples, and of the ``hand_eye`` node's calibration mode.

    Raises:
        ConversionError: the message cannot be decoded.
    """
    if hasattr(msg, "format") and not hasattr(msg, "encoding"):
        return compressed_to_numpy(msg)
    enc = str(msg.encoding).lower()
    if enc.startswith("mono") or enc in ("8uc1", "16uc1"):
        return image_to_numpy(msg, copy=True)
    return image_to_numpy(msg, desired_encoding="bgr16" if "16" in enc else "bgr8", copy=True)
