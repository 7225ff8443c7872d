"""Synthetic eye-in-hand world with exact ground truth.

A UR5e-like arm (:mod:`eye_in_hand.core.kinematics`) carries a distorted stereo rig on
``tool0``; the scene holds coloured spheres, a chessboard and a textured table. Images are
ray-cast through the distorted camera models (:mod:`eye_in_hand.sim.render`); scenarios
(:mod:`eye_in_hand.sim.scenarios`) give calibration poses and localization trajectories; the
writers (:mod:`eye_in_hand.sim.output`) turn them into rosbag2 bags or calibration datasets.

    from eye_in_hand.sim import World
    world = World.default()               # or World.from_yaml("config/world.yaml")
    frame = world.render(q, seed=0)       # frame.left, frame.right (H, W, 3) uint8 BGR
    frame.truth.silhouette_centroid_px_left
"""
from __future__ import annotations

from eye_in_hand.sim.render import Frame, FrameTruth, Renderer
from eye_in_hand.sim.world import DEFAULT_WORLD_YAML, Target, World

__all__ = ["World", "Target", "Frame", "FrameTruth", "Renderer", "DEFAULT_WORLD_YAML"]
