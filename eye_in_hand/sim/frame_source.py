"""The simulator as a stereo camera: the frame source of ``stereo_capture``'s ``sim`` source.

:class:`SimSource` renders the synthetic world (:class:`~eye_in_hand.sim.world.World`) along its
localization trajectory (ping-pong, so that the loop is continuous), or at the latest joint
vector it is given (``follow`` mode: a pair then carries the stamp of the joint state it shows;
while the arm stands still, the last render is handed out again at the camera's rate).
"""
from __future__ import annotations

import threading
import time

import numpy as np

from eye_in_hand.errors import ConfigError, EyeInHandError
from eye_in_hand.io.frame_sources import FrameNotReady, FramePair, FrameSource
from eye_in_hand.sim.scenarios import localization_trajectory
from eye_in_hand.sim.world import World

__all__ = ["SimSource"]


class SimSource(FrameSource):
    """The synthetic world rendered along its localization trajectory (looping), or at the
    latest joint vector given to :meth:`set_joints` (``follow`` mode)."""

    def __init__(self, world: World, rate_hz: float, duration_s: float, seed: int,
                 noise_sigma: float, supersample: int, *, follow: bool = False) -> None:
        self.world = world
        self.follow = follow
        self._lock = threading.Lock()
        self._latest: np.ndarray | None = None
        self._latest_stamp: int | None = None
        self._rendered_stamp: int | None = None
        self._cached: FramePair | None = None      # follow mode: the last render, for a still arm
        self._cached_at = 0.0
        self.period_s = 1.0 / rate_hz
        self.qs: list[np.ndarray] = []
        if not follow:
            try:
                traj = localization_trajectory(world, duration_s, rate_hz, seed)
            except EyeInHandError as exc:
                raise ConfigError(f"sim source: no trajectory ({exc})") from exc
            # ping-pong so that the loop is continuous
            qs = [q for _, q in traj]
            self.qs = qs + qs[-2:0:-1] if len(qs) > 2 else qs
        self.seed = seed
        self.noise_sigma = noise_sigma
        self.supersample = supersample
        self.i = 0
        self.name = "sim (following joint states)" if follow else "sim"

    def set_joints(self, q: np.ndarray, stamp_ns: int | None = None) -> None:
        """Follow mode: render at this joint vector from now on; ``stamp_ns`` (the joint
        state's stamp) becomes the stamp of the pair rendered from it."""
        with self._lock:
            self._latest = np.array(q, dtype=np.float64)
            self._latest_stamp = stamp_ns

    def read(self) -> FramePair:
        stamp = None
        if self.follow:
            with self._lock:
                q = None if self._latest is None else self._latest.copy()
                stamp = self._latest_stamp
            if q is None:
                raise FrameNotReady("no joint state received yet")
            if stamp is not None and stamp == self._rendered_stamp:
                raise FrameNotReady("no new joint state since the last pair")
            cached = self._cached
            if cached is not None and cached.q is not None and np.array_equal(cached.q, q):
                # the arm has not moved since the last render: the camera sees the same scene
                # (a render takes ~0.1-1 s; a real camera streams on), at the camera's rate
                now = time.monotonic()
                if now - self._cached_at < self.period_s:
                    raise FrameNotReady("next frame not due yet")
                self._rendered_stamp, self._cached_at = stamp, now
                k = self.i
                self.i += 1
                return FramePair(cached.left, cached.right, q=q, index=k, stamp_ns=stamp)
            self._rendered_stamp = stamp
        else:
            q = self.qs[self.i % len(self.qs)]
        k = self.i
        self.i += 1
        frame = self.world.render(q, seed=self.seed * 1_000_003 + k,
                                  noise_sigma=self.noise_sigma, supersample=self.supersample)
        pair = FramePair(frame.left, frame.right, q=q, index=k, stamp_ns=stamp)
        if self.follow:
            self._cached, self._cached_at = pair, time.monotonic()
        return pair
