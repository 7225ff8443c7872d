"""Speed of the image conversions on the hot path (per call, median of repeated runs).

Run: ``.venv/bin/python benchmarks/bench_ros_glue.py``

Prints, for a 1280x720 stereo-camera frame: numpy -> Image (one copy into the message),
Image -> numpy for rclpy and rosbags messages (zero-copy views, padded rows included),
big-endian mono16 (one byte-swapping copy), bgr8 -> rgb8 conversion, JPEG/PNG encode and decode,
and a CameraInfo -> CameraModel conversion.
"""
from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from eye_in_hand.core.camera import CameraModel
from eye_in_hand.ros import conversions as conv


def bench(fn: Callable[[], object], repeat: int = 30) -> float:
    """Median wall time of ``fn`` in milliseconds."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def main() -> None:
    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import Stores, get_typestore
    from sensor_msgs.msg import Image

    rng = np.random.default_rng(0)
    h, w = 720, 1280
    y, x = np.mgrid[0:h, 0:w]
    bgr = np.stack([x % 256, y % 256, (x + y) % 256], -1).astype(np.uint8)
    bgr[::7, ::5] = rng.integers(0, 255, size=bgr[::7, ::5].shape, dtype=np.uint8)
    mono16 = rng.integers(0, 65535, size=(h, w), dtype=np.uint16)
    typestore = get_typestore(Stores.ROS2_JAZZY)

    msg = conv.numpy_to_image(bgr, "bgr8")
    raw = serialize_message(msg)
    rb_msg = typestore.deserialize_cdr(raw, "sensor_msgs/msg/Image")
    padded = Image(height=h, width=w, encoding="bgr8", step=w * 3 + 64)
    padded.data = np.zeros(h * (w * 3 + 64), np.uint8).tobytes()
    big = Image(height=h, width=w, encoding="mono16", is_bigendian=1, step=w * 2)
    big.data = mono16.astype(">u2").tobytes()
    jpeg = conv.numpy_to_compressed(bgr, "jpeg")
    png = conv.numpy_to_compressed(bgr, "png")
    cam = CameraModel(K=np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]]),
                      dist=np.zeros(5), width=w, height=h)
    info = conv.model_to_camera_info(cam)

    rows = [
        ("numpy_to_image bgr8 (1 copy)", lambda: conv.numpy_to_image(bgr, "bgr8")),
        ("image_to_numpy rclpy bgr8 (view)", lambda: conv.image_to_numpy(msg)),
        ("image_to_numpy rosbags bgr8 (view)", lambda: conv.image_to_numpy(rb_msg)),
        ("image_to_numpy padded rows (view)", lambda: conv.image_to_numpy(padded)),
        ("image_to_numpy big-endian mono16 (swap)", lambda: conv.image_to_numpy(big)),
        ("image_to_numpy bgr8 -> rgb8", lambda: conv.image_to_numpy(msg, desired_encoding="rgb8")),
        ("image_to_numpy copy=True", lambda: conv.image_to_numpy(msg, copy=True)),
        ("rclpy serialize + deserialize (reference)",
         lambda: deserialize_message(serialize_message(msg), Image)),
        ("numpy_to_compressed jpeg q95", lambda: conv.numpy_to_compressed(bgr, "jpeg")),
        ("compressed_to_numpy jpeg", lambda: conv.compressed_to_numpy(jpeg)),
        ("numpy_to_compressed png level 3", lambda: conv.numpy_to_compressed(bgr, "png")),
        ("compressed_to_numpy png", lambda: conv.compressed_to_numpy(png)),
        ("camera_info_to_model", lambda: conv.camera_info_to_model(info)),
    ]
    print(f"image {w}x{h} bgr8 ({bgr.nbytes / 1e6:.2f} MB); median of 30 runs")
    for name, fn in rows:
        print(f"  {name:<44s} {bench(fn):9.3f} ms")


if __name__ == "__main__":
    main()
