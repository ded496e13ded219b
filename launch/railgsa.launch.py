"""Start irregularity_node and uncertainty_node (and optionally the recorder) from one params file.

    ros2 launch railgsa_ros railgsa.launch.py [params_file:=FILE] [namespace:=NS]
                                              [record:=true] [record_out:=DIR]

For a ROS 2 (Jazzy) install built with colcon; ``railgsa run`` is the same without one. Both
nodes get the SAME params file (default: the package's config/railgsa.yaml, whose ``/**``
section gives both nodes the inversion, vehicle and input values: the band's stamps are those of
track/irregularity only when they are equal). Namespaced nodes read only the sections that
match their namespace (``/**``, ``/**/<node>``, ``/<ns>/<node>``), as rcl does. The nodes are
not renamed (no ``name=``): each keeps its own name in the namespace.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = 'railgsa_ros'
#: the recorded topics (relative ones in the launch namespace)
RECORDED = ['track/irregularity', 'track/irregularity_band', 'track/sensitivity', '/diagnostics']


def generate_launch_description() -> LaunchDescription:
    """The arguments, the two nodes on one params file, and the optional recorder."""
    params = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    arguments = [
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution([FindPackageShare(PACKAGE), 'config',
                                                'railgsa.yaml']),
            description='ROS params file given to both nodes'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of the nodes and their topics'),
        DeclareLaunchArgument('record', default_value='false',
                              description='also record the outputs and /diagnostics'),
        DeclareLaunchArgument('record_out', default_value='railgsa_bag',
                              description='bag directory of the recording (must not exist)'),
    ]
    irregularity = Node(package=PACKAGE, executable='irregularity_node', namespace=namespace,
                        parameters=[params], output='screen')
    uncertainty = Node(package=PACKAGE, executable='uncertainty_node', namespace=namespace,
                       parameters=[params], output='screen')
    recorder = Node(package=PACKAGE, executable='recorder', namespace=namespace,
                    parameters=[{'out': LaunchConfiguration('record_out'), 'topics': RECORDED}],
                    condition=IfCondition(LaunchConfiguration('record')), output='screen')
    return LaunchDescription([*arguments, irregularity, uncertainty, recorder])
