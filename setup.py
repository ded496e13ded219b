"""Build script for railgsa_ros: one tree for pip (``pip install -e .[ros,dev]``) and colcon.

The default install is what the nodes need on a train (numpy, scipy, pyyaml and the bag
libraries); the offline tools that draw, store or spread work come as extras: ``review``
(matplotlib: ``railgsa review``, ``bode``, ``gsa --plot``, ``demo``; tqdm: the progress bar of
``invert``), ``fleet`` (the review's plus DuckDB and Dask: ``railgsa fleet``), ``ros`` (rclpy
from PyPI wheels), ``dev`` (the test and lint tools), ``bench`` (the benchmarks' reference
libraries).
"""

from glob import glob
from pathlib import Path
import re

from setuptools import find_packages, setup

PACKAGE = 'railgsa_ros'


def node_scripts() -> list[str]:
    """One console script per node module (a module of railgsa_ros/nodes with a top-level
    ``def main(``), named after the module: ``ros2 run railgsa_ros <module>``."""
    here = Path(__file__).resolve().parent
    return [f'{path.stem} = {PACKAGE}.nodes.{path.stem}:main'
            for path in sorted((here / PACKAGE / 'nodes').glob('*.py'))
            if re.search(r'^def main\(', path.read_text(encoding='utf-8'), re.MULTILINE)]


ROS = ['ros-jazzy-rclpy==7.1.6', 'ros-jazzy-common-interfaces==5.3.6',
       'ros-jazzy-rmw-fastrtps-cpp==8.4.3']
#: what the nodes import on a train (test_packaging checks that they import nothing else)
RUNTIME = ['numpy>=1.24', 'scipy>=1.11', 'pyyaml>=6', 'rosbags>=0.10', 'mcap>=1.1',
           'zstandard>=0.20', 'threadpoolctl>=3.1']
REVIEW = ['matplotlib>=3.7', 'tqdm>=4.60']
FLEET = [*REVIEW, 'duckdb>=1.1', 'dask[distributed]>=2024.8']  # its report draws like the review
DEV = ['pytest>=7', 'pytest-timeout>=2.1', 'hypothesis>=6', 'ruff>=0.5', 'mypy>=1.10',
       'mcap-ros2-support>=0.5']  # tests write bags with mcap-ros2-support, an independent writer

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'benchmarks']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/config/vehicles', glob('config/vehicles/*.yaml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    python_requires='>=3.11',
    install_requires=RUNTIME,
    extras_require={
        'ros': ROS,
        'review': REVIEW,
        'fleet': FLEET,
        'dev': DEV,
        'bench': ['SALib>=1.5', 'chaospy>=4.3'],
    },
    zip_safe=True,
    maintainer='railgsa developers',
    maintainer_email='railgsa@example.invalid',
    description='Track irregularity from car-body acceleration with uncertainty and sensitivity.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': ['railgsa = railgsa_ros.cli.main:main', *node_scripts()],
    },
)
