"""ros2 launch eye_in_hand eye_in_hand.launch.py [params_file:=FILE] [namespace:=NS]
[start_capture:=true|false] [respawn:=true|false] [respawn_delay:=S]
[mode:=localization|calibration] [composed:=true|false]

The same bring-up as ``eye-in-hand launch``: the nodes, their namespaces, remappings and
calibration-mode parameters come from eye_in_hand/launcher.py (``NODES``, ``CALIBRATION_NODES``,
``COMPOSED``), the environment defaults from eye_in_hand/threads.py (one BLAS thread unless the
user chose a count), as they are now:

* stereo_capture      in <ns>/stereo; ee_pose, joint_states -> <ns>
* detect_triangulate  in <ns>/stereo; target/point, target/point_cov, target/debug_image,
                      targets/markers (and with it every targets/<id>/...) -> <ns>
* hand_eye            in <ns>
* every node's diagnostics -> <ns>/diagnostics

``composed:=true`` (= ``eye-in-hand launch --composed``): detect_triangulate and hand_eye in
one process (executable ``localize``, eye_in_hand/nodes/localize.py), with the same names,
namespaces and topics, the located points handed over in memory.

One parameter file (default: share/eye_in_hand/config/eye_in_hand.yaml) configures all three.

``mode:=calibration`` (= ``eye-in-hand launch --calibrate``): stereo_capture, and hand_eye in
calibration mode with ``left/image_raw``, ``right/image_raw`` (and mono ``image_raw``) remapped
to the camera's ``<ns>/stereo/...``; no detect_triangulate. The default parameter file is then
share/eye_in_hand/config/hand_eye_calibration.yaml. See docs/handeye.md.
A node that exits is restarted after respawn_delay seconds (respawn:=false: it is not); unlike
``eye-in-hand launch``, ros2 launch has a fixed delay and no restart limit.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

import eye_in_hand.launcher as launcher
import eye_in_hand.ros.dds as dds
import eye_in_hand.threads as threads
from launch import LaunchDescription


def _truthy(name, context):
    return LaunchConfiguration(name).perform(context).lower() in ("true", "1", "yes")


def _nodes(context):
    ns = "/" + LaunchConfiguration("namespace").perform(context).strip("/")
    params = LaunchConfiguration("params_file").perform(context)
    mode = LaunchConfiguration("mode").perform(context)
    if mode not in ("localization", "calibration"):
        raise RuntimeError(f"mode:={mode}: must be localization or calibration")
    calibrate = mode == "calibration"
    if not params:
        params = os.path.join(get_package_share_directory("eye_in_hand"), "config",
                              "hand_eye_calibration.yaml" if calibrate else "eye_in_hand.yaml")
    env = threads.blas_env_defaults(os.environ)   # one BLAS thread unless the user chose one
    if not (os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE")
            or os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE")):
        # Large images over shared memory (see eye_in_hand/ros/dds.py).
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(dds.PROFILE)
    again = {"respawn": _truthy("respawn", context),
             "respawn_delay": float(LaunchConfiguration("respawn_delay").perform(context))}

    def node(spec):
        extra = launcher.node_parameters(spec)
        kwargs = {}
        if spec.name == launcher.NODES[0].name:   # the camera
            kwargs["condition"] = IfCondition(LaunchConfiguration("start_capture"))
        return Node(package="eye_in_hand", executable=spec.name, name=spec.name,
                    namespace=launcher.node_namespace(spec, root_namespace=ns),
                    parameters=[params, extra] if extra else [params],
                    remappings=launcher.node_remappings(spec, root_namespace=ns),
                    additional_env=env, output="screen", **again, **kwargs)

    if calibrate:
        return [node(spec) for spec in launcher.CALIBRATION_NODES]
    if _truthy("composed", context):
        # one process; it gives each node its namespace and remappings (as the launcher)
        return [node(launcher.NODES[0]),
                Node(package="eye_in_hand", executable=launcher.COMPOSED.name,
                     arguments=["--namespace", ns], parameters=[params],
                     additional_env=env, output="screen", **again)]
    return [node(spec) for spec in launcher.NODES]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value="",
                              description="ROS parameter file for the nodes (default: "
                              "config/eye_in_hand.yaml, or config/hand_eye_calibration.yaml "
                              "with mode:=calibration)"),
        DeclareLaunchArgument("mode", default_value="localization",
                              choices=["localization", "calibration"],
                              description="localization: the three nodes; calibration: "
                              "stereo_capture and hand_eye in calibration mode"),
        DeclareLaunchArgument("composed", default_value="false",
                              description="detect_triangulate and hand_eye in one process "
                              "(localization mode)"),
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
