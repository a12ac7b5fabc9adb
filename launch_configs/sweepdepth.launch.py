"""ROS 2 launch file for the sweepdepth depth node.

The node runs as a plain process (ExecuteProcess) with its `--ros-args` on the command line,
which it parses itself as rcl would. This file works from two places:

- installed by `colcon build` (package.xml, docs/colcon.md) as
  <prefix>/share/sweepdepth/launch_configs/sweepdepth.launch.py: the package is found in the
  ament index (ament_index_python), the parameter and rig files in its share directory, the
  executable in <prefix>/lib/sweepdepth/:

    ros2 launch sweepdepth sweepdepth.launch.py

- in the source tree (not installed, or another copy installed): the files next to this one,
  the repository root as working directory, `sweepdepth` on PATH:

    ros2 launch launch_configs/sweepdepth.launch.py
    ros2 launch launch_configs/sweepdepth.launch.py \
        params_file:=launch_configs/camera_row.params.yaml namespace:=/row
    ros2 launch launch_configs/sweepdepth.launch.py \
        sweepdepth_bin:=target/release/sweepdepth log_level:=debug

Arguments (`ros2 launch ... --show-args` lists them):
    params_file        ROS 2 parameter file (default: four_cameras.params.yaml next to this file)
    namespace          node namespace; camera topics resolve under it (default: /rig)
    sweepdepth_bin     the sweepdepth executable, a name on PATH or a path (default: the
                       installed <prefix>/lib/sweepdepth/sweepdepth; in the source tree
                       sweepdepth, found on PATH)
    log_level          debug | info | warn | error | fatal (default: info)
    working_directory  where the node runs, so that a relative rig_file (launch_configs/...)
                       resolves (default: the directory above this file: share/sweepdepth
                       installed, the repository root in the source tree)

To include it from another launch file (next to the camera drivers):

    IncludeLaunchDescription(
        PythonLaunchDescriptionSource(os.path.join(
            get_package_share_directory('sweepdepth'), 'launch_configs', 'sweepdepth.launch.py')),
        launch_arguments={'namespace': '/rig'}.items())

(or the path of launch_configs/sweepdepth.launch.py in the source tree).
"""

import os

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, ThisLaunchFileDir


def installed_executable():
    """<prefix>/lib/sweepdepth/sweepdepth when this file is the one colcon installed (it lies in
    the share directory that the ament index gives for the package), else None."""
    try:
        from ament_index_python.packages import get_package_prefix, get_package_share_directory
        share = get_package_share_directory('sweepdepth')
        prefix = get_package_prefix('sweepdepth')
    except (ImportError, LookupError, OSError, ValueError):
        # No ament_index_python, no AMENT_PREFIX_PATH (no ROS environment: an OSError) or no
        # installed sweepdepth package (PackageNotFoundError, a KeyError): the source tree.
        return None
    here = os.path.dirname(os.path.realpath(__file__))
    if here != os.path.join(os.path.realpath(share), 'launch_configs'):
        return None
    return os.path.join(prefix, 'lib', 'sweepdepth', 'sweepdepth')


def generate_launch_description():
    executable = installed_executable()
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
            default_value=executable or 'sweepdepth',
            description='The sweepdepth executable: a name on PATH or a path (default: the '
                        'installed one, or sweepdepth on PATH in the source tree).'),
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
