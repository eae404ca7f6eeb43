"""Launch the RoadBEV node on vehicle topics (a full ROS 2 Jazzy install with launch_ros).

    ros2 launch roadbev_ros roadbev.launch.py \
        left_image:=/cam/left/image_rect right_image:=/cam/right/image_rect \
        left_info:=/cam/left/camera_info right_info:=/cam/right/camera_info imu:=/ins/imu \
        params_file:=/path/to/my_rig.params.yaml backend:=bev_sweep

The ``backend`` argument overrides the params file's ``backend``. The Fast DDS profile (shared
memory with 64 MB segments + UDPv4) is set for every process this launch file starts; camera
drivers started elsewhere need the same FASTRTPS_DEFAULT_PROFILES_FILE or large images are lost
in shared memory.
"""

from __future__ import annotations

from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription

# launch argument -> (default topic the node subscribes to, description)
TOPICS = {
    "left_image": ("/stereo/left/image_rect", "left rectified image"),
    "right_image": ("/stereo/right/image_rect", "right rectified image"),
    "left_info": ("/stereo/left/camera_info", "left CameraInfo"),
    "right_info": ("/stereo/right/camera_info", "right CameraInfo"),
    "imu": ("/imu/data", "IMU (sensor_msgs/Imu)"),
}


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare("roadbev_ros")
    arguments = [
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution([share, "config", "roadbev.params.yaml"]),
            description="ROS 2 params YAML for the node",
        ),
        DeclareLaunchArgument("backend", default_value="bev_sweep",
                              description="bev_sweep, stereo, mono, sgbm or bm"),
        DeclareLaunchArgument(
            "fastdds_profile",
            default_value=PathJoinSubstitution([share, "config", "fastdds.xml"]),
            description="Fast DDS XML profile (large images over shared memory)",
        ),
    ]
    arguments += [
        DeclareLaunchArgument(name, default_value=topic, description=text)
        for name, (topic, text) in TOPICS.items()
    ]
    node = Node(
        package="roadbev_ros",
        executable="roadbev_node",
        name="roadbev",
        output="screen",
        parameters=[LaunchConfiguration("params_file"), {"backend": LaunchConfiguration("backend")}],
        # the node subscribes to <topic> and <topic>/compressed (image_transport:=compressed)
        remappings=[(topic, LaunchConfiguration(name)) for name, (topic, _) in TOPICS.items()]
        + [(f"{TOPICS[n][0]}/compressed", [LaunchConfiguration(n), "/compressed"])
           for n in ("left_image", "right_image")],
    )
    return LaunchDescription(
        [
            *arguments,
            SetEnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE", LaunchConfiguration("fastdds_profile")),
            node,
        ]
    )
