"""Launch the RoadBEV node on vehicle topics (a full ROS 2 Jazzy install with launch_ros).

    ros2 launch roadbev_ros roadbev.launch.py \
        left_image:=/cam/left/image_rect right_image:=/cam/right/image_rect \
        left_info:=/cam/left/camera_info right_info:=/cam/right/camera_info imu:=/ins/imu \
        params_file:=/path/to/my_rig.params.yaml use_sim_time:=true namespace:=front rviz:=true

The params file decides every parameter; ``backend:=NAME`` and ``publish_odom_tf:=true|false``
override it only when given, ``use_sim_time`` always (default false: a replayed bag needs true and
``roadbev replay BAG --clock``). ``namespace`` puts the node (and its relative names: its
services ``~/save_map``, ``~/clear_map``) under a namespace; the topics stay where the remaps put
them (absolute). ``rviz:=true`` also starts RViz with ``rviz_config`` (the shipped view by
default). The node refuses a params file with an unknown or wrong-typed parameter (naming it),
so a typo stops the launch with the reason instead of being ignored. The Fast DDS profile
(shared memory with 64 MB segments + UDPv4) is set for the node only when
FASTRTPS_DEFAULT_PROFILES_FILE is unset; camera drivers started elsewhere need the same profile
or large images are lost in shared memory.
"""

from __future__ import annotations

import os
from typing import Any

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchContext, LaunchDescription

# launch argument -> (default topic the node subscribes to, description)
TOPICS = {
    "left_image": ("/stereo/left/image_rect", "left rectified image"),
    "right_image": ("/stereo/right/image_rect", "right rectified image"),
    "left_info": ("/stereo/left/camera_info", "left CameraInfo"),
    "right_info": ("/stereo/right/camera_info", "right CameraInfo"),
    "imu": ("/imu/data", "IMU (sensor_msgs/Imu)"),
    "odom": ("/odom", "vehicle odometry for the fused road map (nav_msgs/Odometry, odom -> base_link)"),
}


def _flag(context: LaunchContext, name: str) -> bool:
    value = LaunchConfiguration(name).perform(context).strip().lower()
    if value not in ("true", "false"):
        raise ValueError(f"launch argument {name}:={value!r}: expected true or false")
    return bool(value == "true")


def _node(context: LaunchContext, *_args: Any, **_kwargs: Any) -> list[Node]:
    use_sim_time = _flag(context, "use_sim_time")
    parameters: list[Any] = [LaunchConfiguration("params_file").perform(context), {"use_sim_time": use_sim_time}]
    backend = LaunchConfiguration("backend").perform(context)
    if backend:  # only an explicit backend:=NAME overrides the params file
        parameters.append({"backend": backend})
    if LaunchConfiguration("publish_odom_tf").perform(context):
        parameters.append({"publish_odom_tf": _flag(context, "publish_odom_tf")})
    env = {}
    if "FASTRTPS_DEFAULT_PROFILES_FILE" not in os.environ:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = LaunchConfiguration("fastdds_profile").perform(context)
    # with image_transport:=compressed the node follows a remapped image topic to <topic>/compressed
    remappings = [(topic, LaunchConfiguration(name).perform(context)) for name, (topic, _) in TOPICS.items()]
    namespace = LaunchConfiguration("namespace").perform(context)
    nodes = [Node(package="roadbev_ros", executable="roadbev_node", name="roadbev", namespace=namespace,
                  output="screen", parameters=parameters, remappings=remappings, additional_env=env)]
    if _flag(context, "rviz"):
        nodes.append(Node(package="rviz2", executable="rviz2", name="rviz2", namespace=namespace,
                          arguments=["-d", LaunchConfiguration("rviz_config").perform(context)],
                          parameters=[{"use_sim_time": use_sim_time}], additional_env=env))
    return nodes


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare("roadbev_ros")
    arguments = [
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution([share, "config", "roadbev.params.yaml"]),
            description="ROS 2 params YAML for the node (every parameter; unknown names are refused)",
        ),
        DeclareLaunchArgument("backend", default_value="",
                              description="override the params file's backend (ensemble, bm, sgbm, bev_sweep, "
                              "stereo, mono; roadbev node --help lists them)"),
        DeclareLaunchArgument("use_sim_time", default_value="false",
                              description="true: the node (and RViz) run on /clock, for replayed bags"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the node (and RViz)"),
        DeclareLaunchArgument("publish_odom_tf", default_value="",
                              description="true: re-broadcast the odometry as odom -> base_link on /tf (bags and "
                              "vehicles without that TF); empty: the params file decides"),
        DeclareLaunchArgument("rviz", default_value="false", description="true: also start RViz"),
        DeclareLaunchArgument("rviz_config", default_value=PathJoinSubstitution([share, "config", "roadbev.rviz"]),
                              description="RViz configuration (rviz:=true)"),
        DeclareLaunchArgument(
            "fastdds_profile",
            default_value=PathJoinSubstitution([share, "config", "fastdds.xml"]),
            description="Fast DDS XML profile (large images over shared memory), used when "
            "FASTRTPS_DEFAULT_PROFILES_FILE is unset",
        ),
    ]
    arguments += [
        DeclareLaunchArgument(name, default_value=topic, description=text)
        for name, (topic, text) in TOPICS.items()
    ]
    return LaunchDescription([*arguments, OpaqueFunction(function=_node)])
