"""ROS 2 launch file for the sweepdepth depth node.

sweepdepth is a Rust binary, not a ROS package (no ament index, no `ros2 run`), so
launch_ros' Node(package=...) does not apply: the node runs as a plain process with its
`--ros-args` on the command line, which it parses itself as rcl would.

    ros2 launch launch_configs/sweepdepth.launch.py
    ros2 launch launch_configs/sweepdepth.launch.py \
        params_file:=launch_configs/camera_row.params.yaml namespace:=/row
    ros2 launch launch_configs/sweepdepth.launch.py \
        sweepdepth_bin:=target/release/sweepdepth log_level:=debug

Arguments (`ros2 launch ... --show-args` lists them):
    params_file        ROS 2 parameter file (default: four_cameras.params.yaml next to this file)
    namespace          node namespace; camera topics resolve under it (default: /rig)
    sweepdepth_bin     the sweepdepth executable, a name on PATH or a path (default: sweepdepth)
    log_level          debug | info | warn | error | fatal (default: info)
    working_directory  where the node runs, so that a relative rig_file resolves
                       (default: the directory above this file, the repository root)

To include it from another launch file (next to the camera drivers):

    IncludeLaunchDescription(
        PythonLaunchDescriptionSource('/path/to/launch_configs/sweepdepth.launch.py'),
        launch_arguments={'namespace': '/rig'}.items())
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, ThisLaunchFileDir


def generate_launch_description():
    params_file = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    sweepdepth_bin = LaunchConfiguration('sweepdepth_bin')
    log_level = LaunchConfiguration('log_level')
    working_directory = LaunchConfiguration('working_directory')

    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution([ThisLaunchFileDir(), 'four_cameras.params.yaml']),
            description='ROS 2 parameter file for the node (its section must match '
                        '<namespace>/sweepdepth, or be a /** wildcard).'),
        DeclareLaunchArgument(
            'namespace',
            default_value='/rig',
            description='Node namespace (fully qualified); the cameras entries resolve under it.'),
        DeclareLaunchArgument(
            'sweepdepth_bin',
            default_value='sweepdepth',
            description='The sweepdepth executable: a name on PATH or a path.'),
        DeclareLaunchArgument(
            'log_level',
            default_value='info',
            choices=['debug', 'info', 'warn', 'error', 'fatal'],
            description='Log level of the node (--log-level).'),
        DeclareLaunchArgument(
            'working_directory',
            default_value=PathJoinSubstitution([ThisLaunchFileDir(), '..']),
            description='Working directory of the node; a relative rig_file resolves against it.'),
        ExecuteProcess(
            name='sweepdepth',
            cmd=[
                sweepdepth_bin, 'node',
                '--ros-args',
                '--params-file', params_file,
                # A list of text and substitutions is joined into one argument: __ns:=/rig.
                '-r', ['__ns:=', namespace],
                '--log-level', log_level,
            ],
            cwd=working_directory,
            output='screen',
            emulate_tty=True,
            # Give the node time to close its DDS participant on Ctrl-C before SIGKILL.
            sigterm_timeout='10',
        ),
    ])
