"""Launch the RoadBEV node on vehicle topics (a full ROS 2 Jazzy install with launch_ros).

    ros2 launch roadbev_ros roadbev.launch.py \
        left_image:=/cam/left/image_rect right_image:=/cam/right/image_rect \
        left_info:=/cam/left/camera_info right_info:=/cam/right/camera_info imu:=/ins/imu \
        params_file:=/path/to/my_rig.params.yaml

The params file decides every parameter; ``backend:=NAME`` overrides its ``backend`` only when
given. The node refuses a params file with an unknown or wrong-typed parameter (naming it), so a
typo stops the launch with the reason instead of being ignored. The Fast DDS profile (shared
memory with 64 MB segments + UDPv4) is set for the node only when FASTRTPS_DEFAULT_PROFILES_FILE
is unset; camera drivers started elsewhere need the same profile or large images are lost in
shared memory.
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


def _node(context: LaunchContext, *_args: Any, **_kwargs: Any) -> list[Node]:
    parameters: list[Any] = [LaunchConfiguration("params_file").perform(context)]
    backend = LaunchConfiguration("backend").perform(context)
    if backend:  # only an explicit backend:=NAME overrides the params file
        parameters.append({"backend": backend})
    env = {}
    if "FASTRTPS_DEFAULT_PROFILES_FILE" not in os.environ:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = LaunchConfiguration("fastdds_profile").perform(context)
    remappings = [(topic, LaunchConfiguration(name).perform(context)) for name, (topic, _) in TOPICS.items()]
    # the node subscribes to <topic>/compressed with image_transport:=compressed
    remappings += [(f"{TOPICS[n][0]}/compressed", LaunchConfiguration(n).perform(context) + "/compressed")
                   for n in ("left_image", "right_image")]
    return [Node(package="roadbev_ros", executable="roadbev_node", name="roadbev", output="screen",
                 parameters=parameters, remappings=remappings, additional_env=env)]


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare("roadbev_ros")
    arguments = [
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution([share, "config", "roadbev.params.yaml"]),
            description="ROS 2 params YAML for the node (every parameter; unknown names are refused)",
        ),
        DeclareLaunchArgument("backend", default_value="",
                              description="override the params file's backend (bev_sweep, stereo, mono, sgbm, bm)"),
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
