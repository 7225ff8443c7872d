"""Conversions between ROS messages and numpy arrays / core objects (our cv_bridge and tf glue).

This module gathers the conversions kept in one module per message family; import from here or
from the family's module, the names are the same objects:

* :mod:`eye_in_hand.ros.stamps` - int nanoseconds <-> ``Time``, ``Header``.
* :mod:`eye_in_hand.ros.images` - ``Image`` and ``CompressedImage`` <-> numpy.
* :mod:`eye_in_hand.ros.camera_info` - ``CameraInfo`` <-> ``CameraModel``.
* :mod:`eye_in_hand.ros.geometry` - ``Pose``/``Transform``/``Point`` <-> matrices and xyz.
* :mod:`eye_in_hand.ros.fields` - reading message fields with errors that name them.

Two directions, two rules:

* **message -> numpy** functions are *duck-typed*: they only read attributes, so they accept
  messages from rclpy (``data`` is an ``array.array``), messages deserialized by ``rosbags``
  (``data`` is a numpy ``uint8`` array) and anything shaped like them. They never import rclpy or
  message packages, so offline processing runs without ROS installed.
* **numpy -> message** functions build rclpy message objects and import the message classes
  inside the function (the message packages are the optional ``[ros]`` extra).

Every malformed message raises :class:`eye_in_hand.errors.ConversionError` naming the field
(``data``, ``step``, ``encoding``, ``pose.orientation``, ``k``, ...).
"""
from __future__ import annotations

from eye_in_hand.ros.camera_info import camera_info_to_model, model_to_camera_info
from eye_in_hand.ros.geometry import (
    matrix_to_pose,
    matrix_to_pose_stamped,
    matrix_to_transform,
    matrix_to_transform_stamped,
    point_to_xyz,
    pose_to_matrix,
    transform_to_matrix,
    xyz_to_point,
    xyz_to_point_stamped,
)
from eye_in_hand.ros.images import (
    COMPRESSED_FORMATS,
    IMAGE_ENCODINGS,
    compressed_to_numpy,
    convert_encoding,
    image_to_numpy,
    numpy_to_compressed,
    numpy_to_image,
)
from eye_in_hand.ros.stamps import header_stamp_ns, make_header, ns_to_stamp, stamp_to_ns

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
