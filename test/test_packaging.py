"""Packaging: package.xml (REP 149 format 3), setup.py entry points, ROS-free core, the CLI."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path
import re
import shutil
import subprocess
import sys
import tomllib
import xml.etree.ElementTree as ET

import pytest
from setup_helpers import setup_kwargs

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / 'railgsa_ros'
ROS_MODULE = re.compile(r'^(rclpy|rcl_interfaces|builtin_interfaces|rosidl\w*|ament\w*|\w+_msgs|'
                        r'\w+_srvs)$')
#: third-party module -> (its pip requirement, the extra that brings it (None: the default
#: install), its rosdep key (None: the documented pip step of docs/usage.md, rosdistro has none))
THIRD_PARTY = {
    'numpy': ('numpy', None, 'python3-numpy'),
    'scipy': ('scipy', None, 'python3-scipy'),
    'yaml': ('pyyaml', None, 'python3-yaml'),
    'rosbags': ('rosbags', None, 'python3-rosbags-pip'),
    'mcap': ('mcap', None, None),
    'zstandard': ('zstandard', None, None),
    'threadpoolctl': ('threadpoolctl', None, None),
    'matplotlib': ('matplotlib', 'review', None),
    'tqdm': ('tqdm', 'review', None),
    'duckdb': ('duckdb', 'fleet', None),
    'dask': ('dask[distributed]', 'fleet', None),
}
#: what the offline extras bring: no node and no ``railgsa --help`` may load them
OFFLINE_ONLY = ('matplotlib', 'duckdb', 'dask', 'distributed', 'tqdm')


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
    assert 'python3-pytest' in {e.text for e in root.findall('test_depend')}
    setup_version = re.search(r"version='([^']+)'", (REPO / 'setup.py').read_text()).group(1)
    assert setup_version == root.findtext('version')


def requirement_name(requirement: str) -> str:
    """``'dask[distributed]>=2024.8'`` -> ``'dask[distributed]'``."""
    return re.split(r'[<>=!~; ]', requirement, maxsplit=1)[0].lower()


def test_every_third_party_import_is_a_requirement_of_the_default_install_or_an_extra(
        monkeypatch: pytest.MonkeyPatch) -> None:
    imports = set().union(*(top_level_imports(p) for p in PACKAGE.rglob('*.py')))
    third_party = {m for m in imports - set(sys.stdlib_module_names) - {'railgsa_ros'}
                   if not ROS_MODULE.match(m)}
    assert third_party == set(THIRD_PARTY), 'add the module to THIRD_PARTY, setup.py and ' \
        f'package.xml: {third_party ^ set(THIRD_PARTY)}'
    kwargs = setup_kwargs(monkeypatch)
    requires = {requirement_name(r) for r in kwargs['install_requires']}
    extras = {name: {requirement_name(r) for r in reqs}
              for name, reqs in kwargs['extras_require'].items()}
    root = ET.parse(REPO / 'package.xml').getroot()
    exec_deps = {e.text for tag in ('depend', 'exec_depend') for e in root.findall(tag)}
    pip_step = pip_step_requirements()
    for module, (pip_name, extra, key) in THIRD_PARTY.items():
        if extra is None:  # the nodes' run time: pip's default install and the ROS install
            assert pip_name in requires, module
            assert key in exec_deps if key else pip_name in pip_step, module
        else:  # offline tools only: neither install carries them
            assert pip_name in extras[extra] and pip_name not in requires, module
            assert not exec_deps & {f'python3-{pip_name}', f'python3-{pip_name}-pip'}, module
    assert {'numpy', 'scipy', 'pyyaml', 'rosbags', 'mcap'} <= requires
    assert requires.isdisjoint({'matplotlib', 'duckdb', 'dask[distributed]', 'tqdm'})
    assert extras['review'] <= extras['fleet']  # the fleet report draws like the review
    # only the tests need these: not a run-time dependency of either install
    assert {'pytest', 'hypothesis', 'ruff', 'mypy', 'mcap-ros2-support'} <= extras['dev']
    assert not requires & extras['dev'] and 'test' not in extras
    assert 'mcap-ros2-support' in {e.text for e in root.findall('test_depend')}


def pip_step_requirements() -> set[str]:
    """The packages of docs/usage.md's pip step for a ROS install (the ``pip install`` line
    after the ``rosdep install`` line)."""
    text = (REPO / 'docs' / 'usage.md').read_text()
    rosdep = text.index('rosdep install --from-paths src')
    line = next(ln for ln in text[rosdep:].splitlines() if 'pip install' in ln)
    return {requirement_name(w.strip('\'"')) for w in line.split('pip install', 1)[1].split()
            if not w.startswith(('-', '#'))} - {''}


def test_the_nodes_import_only_the_default_install() -> None:
    """Every module the nodes can reach, lazy imports included: no offline library."""
    reached = module_closure([f'railgsa_ros.nodes.{p.stem}'
                              for p in (PACKAGE / 'nodes').glob('*.py')])
    third_party = set().union(*(top_level_imports(module_path(m)) for m in reached))
    third_party -= {*sys.stdlib_module_names, 'railgsa_ros'}
    third_party = {m for m in third_party if not ROS_MODULE.match(m)}
    assert third_party == {m for m, (_, extra, _) in THIRD_PARTY.items() if extra is None}
    assert 'railgsa_ros.inverse.pipeline' in reached and 'railgsa_ros.bag.writer' in reached


def test_nodes_and_the_cli_load_no_offline_library_until_a_command_runs(
        have_rclpy: bool) -> None:
    nodes = [f'railgsa_ros.nodes.{p.stem}' for p in (PACKAGE / 'nodes').glob('*.py')]
    code = ('import importlib, sys\n'
            f'for m in {nodes if have_rclpy else []!r}: importlib.import_module(m)\n'
            'from railgsa_ros.cli.main import build_parser\n'
            'build_parser()\n'
            "print(' '.join(sorted({m.split('.')[0] for m in sys.modules})))\n")
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=120, check=True)
    loaded = set(result.stdout.split())
    assert 'argparse' in loaded and ('rclpy' in loaded) == have_rclpy
    assert loaded.isdisjoint(OFFLINE_ONLY), loaded & set(OFFLINE_ONLY)


def module_closure(roots: list[str]) -> set[str]:
    """The railgsa_ros modules that importing ``roots`` can load, function-level imports
    included (``if TYPE_CHECKING:`` blocks excluded), parent packages too."""
    reached: set[str] = set()
    todo = list(roots)
    while todo:
        name = todo.pop()
        if name in reached or module_path(name) is None:
            continue
        reached.add(name)
        todo.extend('.'.join(name.split('.')[:i]) for i in range(1, name.count('.') + 1))
        todo.extend(m for m in package_imports(name) if m.startswith('railgsa_ros'))
    return reached


def module_path(name: str) -> Path | None:
    """The file of module ``name`` in the repository, or None (a name imported from it)."""
    path = REPO.joinpath(*name.split('.'))
    return next((p for p in (path / '__init__.py', path.with_suffix('.py')) if p.is_file()),
                None)


def package_imports(name: str) -> set[str]:
    """Absolute names of the modules (and ``module.name`` candidates) that module ``name``
    imports outside ``if TYPE_CHECKING:``."""
    path = module_path(name)
    tree = ast.parse(path.read_text(encoding='utf-8'))
    typing_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If)
                   and 'TYPE_CHECKING' in ast.unparse(block.test)
                   for stmt in block.body for n in ast.walk(stmt)}
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    names: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            parts = package.split('.')
            base = node.module if node.level == 0 else '.'.join(
                [*parts[:len(parts) - node.level + 1], *([node.module] if node.module else [])])
            names.add(base)
            names.update(f'{base}.{a.name}' for a in node.names)
    return names


def test_a_command_whose_extra_is_missing_says_so_in_one_line(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        tmp_path: Path) -> None:
    from railgsa_ros.cli.main import main

    monkeypatch.setitem(sys.modules, 'matplotlib', None)  # as if not installed
    bag = tmp_path / 'no_bag'
    assert main(['review', str(bag), '--out', str(tmp_path / 'out')]) == 2
    assert capsys.readouterr().err == (
        "error: railgsa review needs the review extra: pip install 'railgsa_ros[review]'\n")
    assert main(['gsa', '--plot', str(tmp_path / 'plots')]) == 2
    assert 'railgsa gsa needs the review extra' in capsys.readouterr().err
    assert not (tmp_path / 'out').exists() and not (tmp_path / 'plots').exists()
    monkeypatch.setitem(sys.modules, 'duckdb', None)
    assert main(['fleet', 'query', '--db', str(tmp_path / 'f.duckdb'), '--line', 'L',
                 '--from-km', '0', '--to-km', '1']) == 2
    assert capsys.readouterr().err == (
        "error: railgsa fleet needs the fleet extra: pip install 'railgsa_ros[fleet]'\n")


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
