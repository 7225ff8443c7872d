"""Image files read and written through bytes, so that any file name works.

``cv2.imread``/``cv2.imwrite`` take the file name as a C string and crash (segmentation fault)
on names that are not valid UTF-8 (Python holds such names as surrogate escapes). These
helpers do the file I/O in Python (``numpy.fromfile`` / :func:`atomic_write_bytes`) and only
the decoding/encoding in OpenCV (``cv2.imdecode`` / ``cv2.imencode``).
"""
from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from eye_in_hand.errors import InputError
from eye_in_hand.io.atomic import atomic_write_bytes

__all__ = ["read_image_file", "write_image_file", "printable_path"]


def printable_path(path: str | os.PathLike[str]) -> str:
    """``path`` as text any terminal can show (non-UTF-8 bytes as ``\\xNN``)."""
    return os.fspath(path).encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def read_image_file(path: str | os.PathLike[str], flags: int | None = None) -> np.ndarray:
    """Read and decode an image file.

    Args:
        path: the file (any name, including non-UTF-8 bytes).
        flags: ``cv2.IMREAD_*`` (default ``IMREAD_UNCHANGED``: depth and channels kept).

    Returns:
        The image, shape (H, W) or (H, W, C), as ``cv2.imdecode`` gives it (BGR order).

    Raises:
        InputError: ``<path>: cannot read (...)`` or ``<path>: not a readable image file``.
    """
    p = Path(path)
    try:
        data = np.fromfile(p, dtype=np.uint8)
    except OSError as exc:
        raise InputError(f"{printable_path(p)}: cannot read ({exc.strerror or exc})") from exc
    image = (cv2.imdecode(data, cv2.IMREAD_UNCHANGED if flags is None else flags)
             if data.size else None)
    if image is None:
        raise InputError(f"{printable_path(p)}: not a readable image file")
    return image


def write_image_file(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Encode ``image`` by the file's extension (``.png``, ``.jpg``, ...) and write it atomically.

    Raises:
        InputError: the image cannot be encoded in that format.
        OutputWriteError: the file cannot be written (full disk, permissions).
    """
    p = Path(path)
    if not p.suffix.isascii():
        raise InputError(f"{printable_path(p)}: not an image file extension")
    ok, buf = cv2.imencode(p.suffix or ".png", np.asarray(image))
    if not ok:
        raise InputError(f"{printable_path(p)}: cannot encode the image as {p.suffix or '.png'}")
    atomic_write_bytes(p, buf.tobytes())
