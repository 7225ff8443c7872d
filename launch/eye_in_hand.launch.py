"""ros2 launch eye_in_hand eye_in_hand.launch.py [params_file:=FILE] [namespace:=NS]
[start_capture:=true|false] [respawn:=true|false] [respawn_delay:=S]

The same bring-up as ``eye-in-hand launch`` (eye_in_hand/launcher.py: keep the two equal):

* stereo_capture      in <ns>/stereo; ee_pose, joint_states -> <ns>
* detect_triangulate  in <ns>/stereo; target/point, target/point_cov, target/debug_image,
                      targets/markers (and with it every targets/<id>/...) -> <ns>
* hand_eye            in <ns>
* every node's diagnostics -> <ns>/diagnostics

One parameter file (default: share/eye_in_hand/config/eye_in_hand.yaml) configures all three.
A node that exits is restarted after respawn_delay seconds (respawn:=false: it is not); unlike
``eye-in-hand launch``, ros2 launch has a fixed delay and no restart limit.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    ns = "/" + LaunchConfiguration("namespace").perform(context).strip("/")
    root = ns.rstrip("/")
    params = LaunchConfiguration("params_file").perform(context)
    env = {}
    if not (os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE")
            or os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE")):
        # Large images over shared memory (see eye_in_hand/ros/dds.py).
        import eye_in_hand.ros.dds as dds
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(dds.PROFILE)
    diag = ("diagnostics", f"{root}/diagnostics")
    respawn = LaunchConfiguration("respawn").perform(context).lower() in ("true", "1", "yes")
    delay = float(LaunchConfiguration("respawn_delay").perform(context))
    again = {"respawn": respawn, "respawn_delay": delay}
    return [
        Node(package="eye_in_hand", executable="stereo_capture", name="stereo_capture",
             namespace=f"{root}/stereo", parameters=[params], additional_env=env,
             remappings=[("ee_pose", f"{root}/ee_pose"),
                         ("joint_states", f"{root}/joint_states"), diag],
             condition=IfCondition(LaunchConfiguration("start_capture")), output="screen",
             **again),
        Node(package="eye_in_hand", executable="detect_triangulate", name="detect_triangulate",
             namespace=f"{root}/stereo", parameters=[params], additional_env=env,
             remappings=[("target/point", f"{root}/target/point"),
                         ("target/point_cov", f"{root}/target/point_cov"),
                         ("target/debug_image", f"{root}/target/debug_image"),
                         ("targets/markers", f"{root}/targets/markers"), diag],
             output="screen", **again),
        Node(package="eye_in_hand", executable="hand_eye", name="hand_eye", namespace=ns,
             parameters=[params], additional_env=env, remappings=[diag], output="screen",
             **again),
    ]


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory("eye_in_hand"), "config",
                                  "eye_in_hand.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="ROS parameter file for the three nodes"),
        DeclareLaunchArgument("namespace", default_value="/",
                              description="root namespace of every node and topic"),
        DeclareLaunchArgument("start_capture", default_value="true",
                              description="start stereo_capture (false when a bag is replayed)"),
        DeclareLaunchArgument("respawn", default_value="true",
                              description="restart a node that exits"),
        DeclareLaunchArgument("respawn_delay", default_value="2.0",
                              description="seconds before a node that exited is restarted"),
        OpaqueFunction(function=_nodes),
    ])
