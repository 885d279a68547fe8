"""Launch the SMPLify-3D node on the robot (ROS 2 Jazzy).

    ros2 launch smplify3d_ros smplify3d.launch.py
    ros2 launch smplify3d_ros smplify3d.launch.py params_file:=ouster64 points:=/ouster/points rviz:=true

`params_file` is a profile name (params/<name>.yaml in the package share) or a path to a profile YAML
(overrides on top of params/base/*.yaml). The other arguments override the profile for one run when set;
left empty, the profile's value holds.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "smplify3d_ros"

# (launch argument, node parameter, description): per-robot settings; empty keeps the profile's value.
ARGUMENTS = [
    ("image", "topics.image", "sensor_msgs/Image topic"),
    ("compressed_image", "topics.compressed_image", "sensor_msgs/CompressedImage topic (instead of image)"),
    ("camera_info", "topics.camera_info", "sensor_msgs/CameraInfo topic"),
    ("points", "topics.points", "LiDAR sensor_msgs/PointCloud2 topic"),
    ("keypoints", "topics.keypoints", "2D keypoint PointCloud2 (u, v, score, person, joint)"),
    ("init_bodies", "topics.init_bodies", "std_msgs/String bodies JSON with initial estimates"),
    ("output_frame", "output_frame", "frame of the outputs (profile default: the camera optical frame)"),
    ("body_model", "fitting.body.model", "body model: anny or smpl"),
    ("fitting_profile", "fitting.profile", "optimizer profile: robot or thesis"),
    ("device", "fitting.device", "torch device: cpu, cuda or auto"),
]


def _nodes(context, *args, **kwargs):
    parameters = {
        "params_file": LaunchConfiguration("params_file").perform(context),
        "use_sim_time": LaunchConfiguration("use_sim_time").perform(context).lower() in ("true", "1"),
    }
    for arg, name, _ in ARGUMENTS:
        value = LaunchConfiguration(arg).perform(context)
        if value != "":
            parameters[name] = value
    return [Node(
        package=PACKAGE,
        executable="smplify3d_node",
        name="smplify3d",
        namespace=LaunchConfiguration("namespace"),
        output="screen",
        emulate_tty=True,
        parameters=[parameters],
    )]


def generate_launch_description() -> LaunchDescription:
    declared = [
        DeclareLaunchArgument("params_file", default_value="jackal_vlp16",
                              description="profile name (params/<name>.yaml) or path to a profile YAML"),
        DeclareLaunchArgument("namespace", default_value="", description="node namespace"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="use /clock (bag playback)"),
        DeclareLaunchArgument("rviz", default_value="false", description="start RViz with the bundled view"),
    ]
    declared += [DeclareLaunchArgument(arg, default_value="", description=f"{text}; empty: as in the profile")
                 for arg, _, text in ARGUMENTS]
    rviz = Node(
        package="rviz2",
        executable="rviz2",
        name="rviz2",
        arguments=["-d", PathJoinSubstitution([FindPackageShare(PACKAGE), "rviz", "smplify3d.rviz"])],
        parameters=[{"use_sim_time": LaunchConfiguration("use_sim_time")}],
        condition=IfCondition(LaunchConfiguration("rviz")),
    )
    return LaunchDescription([*declared, OpaqueFunction(function=_nodes), rviz])
