"""Start the force_closure node, and RViz showing its markers if asked.

    ros2 launch grasp_fc_ros force_closure.launch.py [params_file:=FILE] [namespace:=NS]
        [node_name:=NAME] [use_sim_time:=true|false] [publish_markers:=true|false]
        [rviz:=true|false] [fixed_frame:=FRAME]

``params_file`` defaults to the installed ``config/force_closure.yaml`` (every parameter at
its default). Its top-level key is the node's name, ``force_closure``: with another
``node_name`` use a file keyed by that name, or by ``/**``. RViz (``rviz:=true``) opens
``rviz/force_closure.rviz``: a MarkerArray display on the node's ``markers`` topic, with
``fixed_frame`` as the fixed frame, which must be the ``header.frame_id`` of the queries
whose markers it should show (or a frame TF connects to it).
"""

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = "grasp_fc_ros"
# The node's console script (setup.py), installed where `ros2 run` and launch look.
EXECUTABLE = "grasp-fc-node"
NODE_NAME = "force_closure"
# The frame the RViz config shows by default; the docs' examples send queries in it.
FIXED_FRAME = "object"
BOOLEAN = ["true", "false"]


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory(PACKAGE)
    arguments = [
        DeclareLaunchArgument(
            "params_file", default_value=f"{share}/config/force_closure.yaml",
            description="YAML parameters file of the node (keyed by its name, or /**)"),
        DeclareLaunchArgument("namespace", default_value="",
                              description="namespace of the node and its topics"),
        DeclareLaunchArgument("node_name", default_value=NODE_NAME,
                              description="name of the node"),
        DeclareLaunchArgument("use_sim_time", default_value="false", choices=BOOLEAN,
                              description="use the /clock topic's time"),
        DeclareLaunchArgument("publish_markers", default_value="false", choices=BOOLEAN,
                              description="publish RViz markers of answered queries "
                                          "(overrides the params file)"),
        DeclareLaunchArgument("rviz", default_value="false", choices=BOOLEAN,
                              description="start RViz with the markers display"),
        DeclareLaunchArgument("fixed_frame", default_value=FIXED_FRAME,
                              description="RViz's fixed frame: the queries' frame_id"),
    ]
    use_sim_time = ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool)
    node = Node(
        package=PACKAGE, executable=EXECUTABLE, name=LaunchConfiguration("node_name"),
        namespace=LaunchConfiguration("namespace"), output="screen", emulate_tty=True,
        parameters=[LaunchConfiguration("params_file"), {
            "use_sim_time": use_sim_time,
            "publish_markers": ParameterValue(LaunchConfiguration("publish_markers"),
                                              value_type=bool)}])
    rviz = Node(
        package="rviz2", executable="rviz2", name="rviz2", output="screen",
        condition=IfCondition(LaunchConfiguration("rviz")),
        arguments=["-d", f"{share}/rviz/force_closure.rviz",
                   "--fixed-frame", LaunchConfiguration("fixed_frame")],
        parameters=[{"use_sim_time": use_sim_time}],
        # The config's display subscribes to /markers; the node publishes in its namespace.
        remappings=[("/markers", [LaunchConfiguration("namespace"), "/markers"])])
    return LaunchDescription([*arguments, node, rviz])
