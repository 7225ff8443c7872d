"""Camera calibration messages: ``sensor_msgs/CameraInfo`` <->
:class:`~eye_in_hand.core.camera.CameraModel`.

The reader is duck-typed (rclpy or rosbags messages) and names the bad field in its
:class:`eye_in_hand.errors.ConversionError`; the builders return rclpy message objects
(:func:`image_camera_info`: the one a camera publishes with each image, calibrated or not).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from eye_in_hand.core.camera import DISTORTION_MODELS, CameraModel
from eye_in_hand.errors import ConfigError, ConversionError, InputError
from eye_in_hand.ros.fields import get_field, read_int, read_str
from eye_in_hand.ros.stamps import header_or_new

__all__ = ["camera_info_to_model", "model_to_camera_info", "image_camera_info"]


def _read_floats(msg: Any, attr: str, size: int | None) -> np.ndarray:
    value = get_field(msg, attr, "")
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
    width = read_int(msg, "width")
    height = read_int(msg, "height")
    if width <= 0 or height <= 0:
        raise ConversionError(f"width/height: image size must be positive, got {width}x{height}")
    model = read_str(msg, "distortion_model")
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
        if hasattr(msg, axis) and read_int(msg, axis) > 1:
            raise ConversionError(f"{axis}: binned camera_info is not supported")
    roi = getattr(msg, "roi", None)
    if roi is not None:
        rw, rh = read_int(roi, "width", "roi"), read_int(roi, "height", "roi")
        rx, ry = read_int(roi, "x_offset", "roi"), read_int(roi, "y_offset", "roi")
        if (rw, rh) != (0, 0) and (rx, ry, rw, rh) != (0, 0, width, height):
            raise ConversionError(
                f"roi: a region of interest ({rx}, {ry}, {rw}x{rh}) is not supported")
    projection: Any = P if np.any(P) else None      # None: CameraModel's [K | 0]
    try:
        return CameraModel(K=K, dist=d, width=width, height=height, distortion_model=model,
                           R=R, P=projection, name=name)
    except InputError as exc:
        raise ConversionError(f"camera_info: {exc}") from exc


def model_to_camera_info(model: Any, *, stamp_ns: int = 0, frame_id: str = "",
                         header: Any = None) -> Any:
    """A ``sensor_msgs.msg.CameraInfo`` from a camera model (binning 1, full-image roi).

    Args:
        model: a :class:`eye_in_hand.core.camera.CameraModel`.
        stamp_ns, frame_id, header: as in :func:`numpy_to_image`.
    """
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from sensor_msgs.msg import CameraInfo

    msg = CameraInfo()
    msg.header = header_or_new(header, stamp_ns, frame_id)
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



def image_camera_info(model: Any, width: int, height: int, header: Any) -> Any:
    """The ``sensor_msgs.msg.CameraInfo`` to publish with a ``width`` x ``height`` image.

    Args:
        model: the camera's :class:`~eye_in_hand.core.camera.CameraModel`, or None when it is
            uncalibrated: then the size only, as camera drivers publish it.
        width, height: the image's size.
        header: the image's header.

    Raises:
        ConfigError: the model is calibrated for another image size.
    """
    if model is None:  # uncalibrated: size only, as camera drivers publish it
        # local: message packages are the optional [ros] extra; decoding and offline code import
        # this module without them
        from sensor_msgs.msg import CameraInfo

        info = CameraInfo()
        info.header = header
        info.width, info.height = width, height
        return info
    if (model.width, model.height) != (width, height):
        raise ConfigError(f"camera_info is {model.width}x{model.height} but the image is "
                          f"{width}x{height}")
    return model_to_camera_info(model, header=header)
