"""Fixtures of the ROS glue tests: the rosbags Jazzy typestore and message builders."""
from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def typestore():
    """The rosbags type store of ROS 2 Jazzy (message classes used by offline processing)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)
