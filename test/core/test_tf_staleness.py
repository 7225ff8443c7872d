"""The staleness rules of the robot pose hold when the pose comes from TF (``TfPoseView``).

The same three rules as for ``ee_pose`` / ``joint_states`` (``PoseBuffer``): a chain last covered
by transforms received too long ago is refused (``stale_pose``), a transform far behind the
chain's newest stamp (a bag loop, a replay) clears the dynamic transforms, and a stream that
stopped is expired. Static transforms survive every clear.
"""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core.tf import TfBuffer, TfPoseView
from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.errors import LocalizationError

S = 1_000_000_000
T0 = 100 * S
GAP = S // 10


def _feed(view: TfPoseView, stamps, received=None) -> None:
    """base_link -> base static, base -> tool0 dynamic at each stamp, received as given."""
    received = stamps if received is None else received
    for stamp, recv in zip(stamps, received, strict=True):
        view.check_jump(stamp, recv)
        view.buffer.set_transform("base", "tool0", stamp,
                                  from_rotvec([0, 0, 1e-9 * (stamp - T0)], [0.4, 0, 0.3]))
        view.received(recv)


def _view() -> TfPoseView:
    buf = TfBuffer(1000)
    buf.set_transform("base_link", "base", 0, from_rotvec([0, 0, np.pi], [0, 0, 0]), static=True)
    return TfPoseView(buf, "base_link", "tool0", jump_back_ns=S)


def test_receive_age_refuses_a_chain_received_too_long_ago() -> None:
    view = _view()
    _feed(view, [T0 + k * S // 20 for k in range(21)])            # 1 s at 20 Hz
    ok = view.lookup(T0 + S // 2, GAP, now_ns=T0 + S, max_age_ns=S)
    assert ok.shape == (4, 4)
    with pytest.raises(LocalizationError) as err:
        view.lookup(T0 + S // 2, GAP, now_ns=T0 + 3 * S, max_age_ns=S)
    assert err.value.reason == "stale_pose"


def test_a_jump_back_in_time_clears_the_dynamic_transforms() -> None:
    view = _view()
    _feed(view, [T0 + k * S // 20 for k in range(41)])            # 2 s
    # the bag starts again: its first transform is 2 s behind the newest
    assert view.check_jump(T0, T0 + 2 * S + S // 20)
    assert view.resets["time_jump"] == 1
    with pytest.raises(LocalizationError) as err:
        view.lookup(T0 + S // 2, GAP)
    assert err.value.reason == "no_robot_pose"  # the TF buffer has no tool0 transform now
    # static transforms stay; the replay's own transforms are used from then on
    assert view.buffer.is_static("base")
    _feed(view, [T0 + k * S // 20 for k in range(5)],
          [T0 + 3 * S + k * S // 20 for k in range(5)])
    view.lookup(T0 + S // 10, GAP, now_ns=T0 + 3 * S + S // 5, max_age_ns=S)


def test_a_stopped_stream_is_expired() -> None:
    view = _view()
    _feed(view, [T0 + k * S // 20 for k in range(21)])
    assert view.expire(T0 + S + S // 2, S) is None
    assert view.expire(T0 + 3 * S, S) == "stream_stopped"
    assert view.resets["stream_stopped"] == 1 and view.newest_ns is None
    assert view.buffer.is_static("base")
