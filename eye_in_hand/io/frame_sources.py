"""Stereo frame sources from files and devices: image files, videos, cameras.

A :class:`FrameSource` produces stereo pairs (:class:`FramePair`) for the ``stereo_capture``
node, which reads them on a worker thread and publishes them: :class:`ImageFilesSource`
(folders or glob patterns of image files, in sorted order), :class:`CaptureSource`
(``cv2.VideoCapture``: video files or v4l2 devices, two streams or one side-by-side stream).
The simulator's source is
:class:`eye_in_hand.sim.frame_source.SimSource`. A source that cannot be opened raises
:class:`~eye_in_hand.errors.ConfigError` naming the parameter; one frame that cannot be read
raises :class:`FrameReadError` and the source stays usable.
"""
from __future__ import annotations

import glob
import os
from pathlib import Path

import cv2
import numpy as np

from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.io.images import read_image_file

__all__ = ["FramePair", "FrameReadError", "FrameNotReady", "FrameSource", "ImageFilesSource",
           "CaptureSource"]

_IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


class FramePair:
    """One stereo pair of a :class:`FrameSource`: BGR images, the joint vector it was rendered
    at (simulator only), its index in the source and, when the source knows it, its stamp."""

    __slots__ = ("left", "right", "q", "index", "stamp_ns")

    def __init__(self, left: np.ndarray, right: np.ndarray, q: np.ndarray | None = None,
                 index: int = 0, stamp_ns: int | None = None) -> None:
        self.left, self.right, self.q, self.index = left, right, q, index
        self.stamp_ns = stamp_ns   # the time of the arm state shown (None: stamp when published)


class FrameReadError(Exception):
    """One frame could not be read (the source stays usable)."""


class FrameNotReady(Exception):
    """No frame can be produced yet (e.g. no joint state received); not a failure."""


class FrameSource:
    """A producer of stereo pairs. ``read()`` returns a pair, raises :class:`FrameReadError`
    for one bad frame (or :class:`FrameNotReady` when none can be produced yet), or returns
    None at the end of a non-looping source."""

    name = "source"

    def read(self) -> FramePair | None:  # pragma: no cover - interface
        raise NotImplementedError

    def close(self) -> None:
        """Release devices and files."""


def _list_images(spec: str, what: str) -> list[str]:
    if not spec:
        raise ConfigError(f"parameter '{what}': images source needs a folder or glob pattern")
    if os.path.isdir(spec):
        files = [str(p) for p in Path(spec).iterdir() if p.suffix.lower() in _IMAGE_EXTS]
    else:
        files = [f for f in glob.glob(spec) if os.path.isfile(f)]
    if not files:
        raise ConfigError(f"parameter '{what}': no images found at {spec!r}")
    return sorted(files)


class ImageFilesSource(FrameSource):
    """Pairs of image files, in sorted order (left i with right i)."""

    def __init__(self, left: str, right: str, loop: bool) -> None:
        self.left = _list_images(left, "images.left")
        self.right = _list_images(right, "images.right")
        if len(self.left) != len(self.right):
            raise ConfigError(f"images source: {len(self.left)} left images ({left!r}) but "
                              f"{len(self.right)} right images ({right!r})")
        self.loop = loop
        self.i = 0
        self.name = f"images {left} | {right}"

    def read(self) -> FramePair | None:
        if self.i >= len(self.left):
            if not self.loop:
                return None
            self.i = 0
        i = self.i
        self.i += 1
        imgs = []
        for path in (self.left[i], self.right[i]):
            try:
                img = read_image_file(path, cv2.IMREAD_COLOR)
            except InputError as exc:
                raise FrameReadError(str(exc)) from exc
            imgs.append(img)
        return FramePair(imgs[0], imgs[1], index=i)


def _open_capture(spec: str, what: str, width: int = 0, height: int = 0) -> cv2.VideoCapture:
    target: int | str = int(spec) if spec.strip().isdigit() else spec
    cap = cv2.VideoCapture(target)
    if not cap.isOpened():
        raise ConfigError(f"parameter '{what}': cannot open {spec!r}")
    if width > 0:
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
    if height > 0:
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
    return cap


class CaptureSource(FrameSource):
    """Two ``cv2.VideoCapture`` streams, or one side-by-side stream split in halves."""

    def __init__(self, left: str, right: str, side_by_side: bool, *, prefix: str,
                 loop: bool = False, width: int = 0, height: int = 0) -> None:
        self.prefix = prefix
        self.loop = loop
        self.side_by_side = side_by_side
        self.caps = [_open_capture(left, f"{prefix}.left",
                                   width * (2 if side_by_side else 1), height)]
        if not side_by_side:
            if not right:
                raise ConfigError(f"parameter '{prefix}.right': needed unless side_by_side")
            try:
                self.caps.append(_open_capture(right, f"{prefix}.right", width, height))
            except ConfigError:
                self.caps[0].release()
                raise
        self.name = f"{prefix} {left}" + ("" if side_by_side else f" | {right}")
        self.index = 0

    def _grab(self) -> list[np.ndarray] | None:
        frames = []
        for cap in self.caps:  # grab both first, then retrieve: closest capture times
            if not cap.grab():
                return None
        for k, cap in enumerate(self.caps):
            ok, img = cap.retrieve()
            if not ok or img is None:
                raise FrameReadError(f"{self.prefix}: cannot decode frame {self.index} "
                                   f"of stream {k}")
            frames.append(img)
        return frames

    def read(self) -> FramePair | None:
        frames = self._grab()
        if frames is None:
            if self.prefix == "video" and self.loop:
                for cap in self.caps:
                    cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                frames = self._grab()
            if frames is None:
                if self.prefix == "v4l2":
                    raise FrameReadError(f"v4l2: frame {self.index} could not be grabbed")
                return None
        self.index += 1
        if self.side_by_side:
            img = frames[0]
            w = img.shape[1]
            if w % 2:
                raise FrameReadError(f"{self.prefix}: side-by-side frame width {w} is odd")
            left, right = img[:, :w // 2], img[:, w // 2:]
        else:
            left, right = frames
        if left.ndim == 2:
            left = cv2.cvtColor(left, cv2.COLOR_GRAY2BGR)
            right = cv2.cvtColor(right, cv2.COLOR_GRAY2BGR)
        return FramePair(np.ascontiguousarray(left), np.ascontiguousarray(right),
                     index=self.index - 1)

    def close(self) -> None:
        for cap in self.caps:
            cap.release()
