"""Packaging: package.xml (REP 149 format 3), setup.py entry points, ROS-free core, the CLI."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path
import re
import runpy
import shutil
import subprocess
import sys
import tomllib
from typing import Any
import xml.etree.ElementTree as ET

import pytest
import setuptools

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / 'railgsa_ros'
ROS_MODULE = re.compile(r'^(rclpy|rcl_interfaces|builtin_interfaces|rosidl\w*|ament\w*|\w+_msgs|'
                        r'\w+_srvs)$')
#: third-party module -> (its pip requirement names, its rosdep keys): what a pip install and a
#: ROS install must both provide for the package's imports
THIRD_PARTY = {
    'numpy': (('numpy',), ('python3-numpy',)),
    'scipy': (('scipy',), ('python3-scipy',)),
    'yaml': (('pyyaml',), ('python3-yaml',)),
    'matplotlib': (('matplotlib',), ('python3-matplotlib',)),
    'rosbags': (('rosbags',), ('python3-rosbags-pip',)),
    'mcap': (('mcap',), ('python3-mcap-pip',)),
    'zstandard': (('zstandard',), ('python3-zstandard',)),
    'threadpoolctl': (('threadpoolctl',), ('python3-threadpoolctl',)),
    'duckdb': (('duckdb',), ('python3-duckdb-pip',)),
    'dask': (('dask[distributed]',), ('python3-dask-pip', 'python3-distributed-pip')),
}


def setup_kwargs(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """The keyword arguments setup.py passes to setuptools.setup (nothing is built)."""
    captured: dict[str, Any] = {}
    monkeypatch.setattr(setuptools, 'setup', lambda **kw: captured.update(kw))
    monkeypatch.chdir(REPO)
    runpy.run_path(str(REPO / 'setup.py'), run_name='__main__')
    return captured


def top_level_imports(path: Path) -> set[str]:
    """First components of every module imported anywhere in a Python file."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
        if isinstance(node, ast.Import):
            names.update(a.name.split('.')[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split('.')[0])
    return names


def test_package_xml_format3_with_the_real_dependencies() -> None:
    root = ET.parse(REPO / 'package.xml').getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    assert root.findtext('name') == 'railgsa_ros'
    assert re.fullmatch(r'\d+\.\d+\.\d+', root.findtext('version'))
    assert root.findtext('description').strip()
    assert all(m.get('email') for m in root.findall('maintainer')) and root.findall('maintainer')
    assert root.findtext('license') == 'Apache-2.0'
    assert root.findtext('export/build_type') == 'ament_python'
    exec_deps = {e.text for tag in ('depend', 'exec_depend') for e in root.findall(tag)}
    ros_imports = set().union(*(top_level_imports(p) for p in PACKAGE.rglob('*.py')))
    ros_imports = {m for m in ros_imports if ROS_MODULE.match(m)}
    assert {'rclpy', 'sensor_msgs', 'nav_msgs', 'geometry_msgs'} <= ros_imports
    assert ros_imports <= exec_deps, ros_imports - exec_deps
    for key in ('python3-numpy', 'python3-scipy', 'python3-yaml', 'python3-matplotlib'):
        assert key in exec_deps
    assert 'python3-pytest' in {e.text for e in root.findall('test_depend')}
    setup_version = re.search(r"version='([^']+)'", (REPO / 'setup.py').read_text()).group(1)
    assert setup_version == root.findtext('version')


def requirement_name(requirement: str) -> str:
    """``'dask[distributed]>=2024.8'`` -> ``'dask[distributed]'``."""
    return re.split(r'[<>=!~; ]', requirement, maxsplit=1)[0].lower()


def test_every_third_party_import_is_a_pip_and_a_rosdep_dependency(
        monkeypatch: pytest.MonkeyPatch) -> None:
    imports = set().union(*(top_level_imports(p) for p in PACKAGE.rglob('*.py')))
    third_party = {m for m in imports - set(sys.stdlib_module_names) - {'railgsa_ros'}
                   if not ROS_MODULE.match(m)}
    assert third_party == set(THIRD_PARTY), 'add the module to THIRD_PARTY, setup.py and ' \
        f'package.xml: {third_party ^ set(THIRD_PARTY)}'
    requires = {requirement_name(r) for r in setup_kwargs(monkeypatch)['install_requires']}
    root = ET.parse(REPO / 'package.xml').getroot()
    exec_deps = {e.text for tag in ('depend', 'exec_depend') for e in root.findall(tag)}
    for module, (pip_names, keys) in THIRD_PARTY.items():
        assert set(pip_names) <= requires, (module, pip_names)
        assert set(keys) <= exec_deps, (module, keys)
    # only the tests need these: not a run-time dependency of either install
    assert 'mcap-ros2-support' not in requires
    test_extra = {requirement_name(r) for r in setup_kwargs(monkeypatch)['extras_require']['test']}
    assert {'pytest', 'hypothesis', 'mcap-ros2-support'} <= test_extra
    assert 'python3-mcap-ros2-support-pip' in {e.text for e in root.findall('test_depend')}


def test_setup_entry_points_import(monkeypatch: pytest.MonkeyPatch, have_rclpy: bool) -> None:
    kwargs = setup_kwargs(monkeypatch)
    scripts = dict(s.replace(' ', '').split('=') for s in
                   kwargs['entry_points']['console_scripts'])
    assert scripts['railgsa'] == 'railgsa_ros.cli.main:main'
    assert scripts['imu_sim_node'] == 'railgsa_ros.nodes.imu_sim_node:main'
    node_mains = {p.stem for p in (PACKAGE / 'nodes').glob('*.py')
                  if re.search(r'^def main\(', p.read_text(), re.MULTILINE)}
    assert node_mains <= set(scripts)
    for target in scripts.values():
        module, attr = target.split(':')
        if module.startswith('railgsa_ros.nodes.') and not have_rclpy:
            continue  # the nodes need the ros extra
        assert callable(getattr(importlib.import_module(module), attr)), target
    assert 'test' not in kwargs['packages'] and 'railgsa_ros.bag' in kwargs['packages']
    for pattern in kwargs.get('package_data', {}).get('railgsa_ros', []):
        assert list(PACKAGE.glob(pattern)), pattern  # no package data that does not exist
    data = dict(kwargs['data_files'])
    assert data['share/ament_index/resource_index/packages'] == ['resource/railgsa_ros']
    assert (REPO / 'resource' / 'railgsa_ros').is_file()
    assert 'config/imu_sim.yaml' in data['share/railgsa_ros/config']
    assert not any(r.startswith('rclpy') for r in kwargs['install_requires'])
    assert any(r.startswith('ros-jazzy-rclpy==') for r in kwargs['extras_require']['ros'])
    cfg = (REPO / 'setup.cfg').read_text()
    assert 'script_dir=$base/lib/railgsa_ros' in cfg
    assert 'install_scripts=$base/lib/railgsa_ros' in cfg
    pyproject = tomllib.loads((REPO / 'pyproject.toml').read_text())
    assert 'project' not in pyproject  # colcon-ros runs setup.py


def test_core_imports_no_ros_and_needs_no_share_directory() -> None:
    offenders = {}
    for path in PACKAGE.rglob('*.py'):
        if 'nodes' in path.relative_to(PACKAGE).parts:
            continue
        ros = {m for m in top_level_imports(path) if ROS_MODULE.match(m)}
        if ros:
            offenders[str(path.relative_to(REPO))] = ros
        assert 'get_package_share_directory' not in path.read_text(), path
    assert offenders == {}, f'ROS imports outside railgsa_ros/nodes/ (move them): {offenders}'


def test_installed_railgsa_script_lists_the_subcommands() -> None:
    script = Path(sys.executable).parent / 'railgsa'
    if not script.exists():
        script = shutil.which('railgsa')
    if script is None:
        pytest.skip('railgsa console script not installed (pip install -e .)')
    result = subprocess.run([str(script), '--help'], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0
    for command in ('simulate', 'bode', 'demo'):
        assert re.search(rf'^    {command}\s', result.stdout, re.MULTILINE), command
