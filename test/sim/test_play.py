"""A simulated bag replays over DDS with ``eye-in-hand play``."""
from __future__ import annotations

import subprocess
import sys

import pytest

rclpy = pytest.importorskip("rclpy")


def test_simulated_bag_replays_with_play(tmp_path, small_world, ros_context, executor,
                                         spin_until, ros_env):
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Image

    from eye_in_hand.sim.output import RenderOptions, write_bag

    world = small_world.with_image_size(160, 120)
    bag = tmp_path / "sim"
    write_bag(world, bag, scenario="localization", frames=5, seed=2,
              render=RenderOptions(noise_sigma=0.0))
    node = rclpy.create_node("sim_play_listener", context=ros_context)
    got: dict[str, list] = {"left": [], "right": [], "pose": []}
    from rclpy.qos import qos_profile_sensor_data

    node.create_subscription(Image, "/stereo/left/image_raw", got["left"].append,
                             qos_profile_sensor_data)
    node.create_subscription(Image, "/stereo/right/image_raw", got["right"].append,
                             qos_profile_sensor_data)
    node.create_subscription(PoseStamped, "/ee_pose", got["pose"].append, 100)
    executor.add_node(node)
    proc = subprocess.Popen([sys.executable, "-m", "eye_in_hand.cli", "play", str(bag),
                             "--wait-for-subscribers", "20",
                             "--topics", "/stereo/left/image_raw", "/stereo/right/image_raw",
                             "/ee_pose"],
                            env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        ok = spin_until(executor, lambda: len(got["right"]) >= 5 and len(got["pose"]) >= 20,
                        60.0)
        assert ok, {k: len(v) for k, v in got.items()}
    finally:
        try:
            out, _ = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
    assert proc.returncode == 0, out.decode(errors="replace")

    def stamps(msgs: list) -> list[int]:
        return [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs]

    assert stamps(got["left"]) == stamps(got["right"])
    assert got["left"][0].width == 160 and got["left"][0].encoding == "bgr8"
