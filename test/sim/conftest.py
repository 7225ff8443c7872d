"""Shared fixtures of the simulator tests."""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core.transforms import compose, invert
from eye_in_hand.sim import World
from eye_in_hand.sim.scenarios import HOME_Q, look_at


@pytest.fixture(scope="session")
def world() -> World:
    """The default world (1280x720)."""
    return World.default()


@pytest.fixture(scope="session")
def small_world() -> World:
    """The default world at 320x240 (most rendering tests)."""
    return World.default().with_image_size(320, 240)


def q_looking_at(world: World, target, eye, roll: float = 0.0) -> np.ndarray:
    """Joint vector that puts the left camera at ``eye`` looking at ``target``."""
    base_T_cam = look_at(np.asarray(target, float), np.asarray(eye, float), roll)
    return world.arm.ik(compose(base_T_cam, invert(world.ee_T_cam)), HOME_Q)


@pytest.fixture(scope="session")
def q_at():
    return q_looking_at
