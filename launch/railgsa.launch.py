"""Start irregularity_node and uncertainty_node (and optionally the recorder) from one params file.

    ros2 launch railgsa_ros railgsa.launch.py [params_file:=FILE] [namespace:=NS]
        [imu_topic:=TOPIC] [odom_topic:=TOPIC] [use_sim_time:=true] [log_level:=LEVEL]
        [record:=true] [record_out:=DIR]

For a ROS 2 (Jazzy) install built with colcon; ``railgsa run`` is the same without one. Both
nodes get the SAME params file (default: the package's config/railgsa.yaml, whose ``/**``
section gives both nodes the inversion, vehicle and input values: the band's stamps are those of
track/irregularity only when they are equal). Namespaced nodes read only the sections that
match their namespace (``/**``, ``/**/<node>``, ``/<ns>/<node>``), as rcl does. The nodes are
not renamed (no ``name=``): each keeps its own name in the namespace.

``imu_topic`` and ``odom_topic`` remap the nodes' inputs (``imu/data``, ``odom``; relative names
resolve in the namespace, ``/imu`` does not). ``use_sim_time`` (given after the params file, so
it wins over a value there) and ``log_level`` (debug, info, warn, error, fatal) apply to every
node started, the recorder too.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

PACKAGE = 'railgsa_ros'
#: the recorded topics (relative ones in the launch namespace)
RECORDED = ['track/irregularity', 'track/irregularity_band', 'track/sensitivity', '/diagnostics']
#: the nodes' input topics (as they subscribe them) -> the launch argument that remaps each
INPUTS = {'imu/data': 'imu_topic', 'odom': 'odom_topic'}


def generate_launch_description() -> LaunchDescription:
    """The arguments, the two nodes on one params file, and the optional recorder."""
    params = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    sim_time = {'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'),
                                               value_type=bool)}
    ros_arguments = ['--log-level', LaunchConfiguration('log_level')]
    remappings = [(topic, LaunchConfiguration(argument)) for topic, argument in INPUTS.items()]
    arguments = [
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution([FindPackageShare(PACKAGE), 'config',
                                                'railgsa.yaml']),
            description='ROS params file given to both nodes'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of the nodes and their topics'),
        *(DeclareLaunchArgument(argument, default_value=topic,
                                description=f'topic the nodes read as {topic}')
          for topic, argument in INPUTS.items()),
        DeclareLaunchArgument('use_sim_time', default_value='false', choices=['true', 'false'],
                              description='stamp with /clock instead of the system clock'),
        DeclareLaunchArgument('log_level', default_value='info',
                              choices=['debug', 'info', 'warn', 'error', 'fatal'],
                              description='log level of every node'),
        DeclareLaunchArgument('record', default_value='false',
                              description='also record the outputs and /diagnostics'),
        DeclareLaunchArgument('record_out', default_value='railgsa_bag',
                              description='bag directory of the recording (must not exist)'),
    ]
    irregularity = Node(package=PACKAGE, executable='irregularity_node', namespace=namespace,
                        parameters=[params, sim_time], remappings=remappings,
                        ros_arguments=ros_arguments, output='screen')
    uncertainty = Node(package=PACKAGE, executable='uncertainty_node', namespace=namespace,
                       parameters=[params, sim_time], remappings=remappings,
                       ros_arguments=ros_arguments, output='screen')
    recorder = Node(package=PACKAGE, executable='recorder', namespace=namespace,
                    parameters=[{'out': LaunchConfiguration('record_out'), 'topics': RECORDED},
                                sim_time],
                    ros_arguments=ros_arguments,
                    condition=IfCondition(LaunchConfiguration('record')), output='screen')
    return LaunchDescription([*arguments, irregularity, uncertainty, recorder])
