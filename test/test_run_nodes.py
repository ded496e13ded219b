"""Starting the nodes: ``railgsa run`` (the PyPI path) and launch/railgsa.launch.py (a ROS
install; parsed, launch is not installable here), both from one params file."""

from __future__ import annotations

import ast
from pathlib import Path
import re
import signal
import subprocess
import sys
import time
from typing import Any

import pytest

from railgsa_ros.cli.main import main

REPO = Path(__file__).resolve().parents[1]
LAUNCH = REPO / 'launch' / 'railgsa.launch.py'
NODES = ('irregularity_node', 'uncertainty_node')


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / 'params.yaml'
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------- the params check
@pytest.mark.ros
def test_shipped_params_file_gives_both_nodes_the_defaults_in_any_namespace() -> None:
    from railgsa_ros.cli.run import node_values
    from railgsa_ros.nodes.specs import (
        INVERSION_SPECS,
        NODE_SPECS,
        UNCERTAINTY_SPECS,
        VEHICLE_SPECS,
    )

    common = (*INVERSION_SPECS, *VEHICLE_SPECS, *NODE_SPECS)
    for namespace in ('/', '/train1', '/fleet/train2'):
        values = node_values(str(REPO / 'config' / 'railgsa.yaml'), namespace)
        assert values['irregularity_node'] == {s.name: s.default for s in common}
        assert values['uncertainty_node'] == {s.name: s.default
                                              for s in (*common, *UNCERTAINTY_SPECS)}


@pytest.mark.ros
@pytest.mark.parametrize(('text', 'namespace', 'needle'), [
    ('/**:\n  ros__parameters:\n    bandd: d2\n', '', 'unknown parameter(s) bandd (did you '
     'mean band?)'),
    # rcl applies a bare "irregularity_node:" only in the root namespace
    ('irregularity_node:\n  ros__parameters:\n    band: d2\n', 'train1',
     'no section for node irregularity_node'),
    ('/**:\n  ros__parameters:\n    band: d2\n/**/uncertainty_node:\n  ros__parameters:\n'
     '    band: d1\n', '', "different values of band (band: 'd2' and 'd1')"),
    ('/**:\n  ros__parameters:\n    band: d9\n', '', 'irregularity_node: band:'),
    ('/**/uncertainty_node:\n  ros__parameters:\n    rule: pem9\n/**:\n  ros__parameters: {}\n',
     '', 'uncertainty_node: '),
    ('/**:\n  ros__parameters:\n    band: [d1\n', '', 'invalid YAML'),
])
def test_bad_params_file_is_one_line_exit_2_before_anything_starts(
        tmp_path: Path, capsys: Any, text: str, namespace: str, needle: str) -> None:
    path = write(tmp_path, text)
    started = time.monotonic()
    assert main(['run', '--params', str(path), '--namespace', namespace]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'error: {path}: ') and needle in err and err.count('\n') == 1, err
    assert time.monotonic() - started < 10  # refused at once, no node started


@pytest.mark.ros
def test_a_namespaced_node_refuses_a_section_rcl_would_ignore(tmp_path: Path) -> None:
    """``ros2 launch ... namespace:=train1`` with a bare ``irregularity_node:`` section: rcl
    would run the node on its defaults; the node's own check refuses the file."""
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.nodes.params import check_params_files
    from railgsa_ros.nodes.specs import ALL_PARAMETER_NAMES

    bare = write(tmp_path, 'irregularity_node:\n  ros__parameters:\n    band: d2\n')
    args = ['--ros-args', '-r', '__ns:=/train1', '--params-file', str(bare)]
    with pytest.raises(ConfigError, match='no section for node irregularity_node'):
        check_params_files(args, 'irregularity_node', {'band'}, ALL_PARAMETER_NAMES)
    check_params_files(args[3:], 'irregularity_node', {'band'}, ALL_PARAMETER_NAMES)  # root
    bare.write_text('/**/irregularity_node:\n  ros__parameters:\n    band: d2\n')
    check_params_files(args, 'irregularity_node', {'band'}, ALL_PARAMETER_NAMES)


def test_namespace_is_checked() -> None:
    from railgsa_ros.cli.run import namespace_of
    from railgsa_ros.errors import ConfigError

    assert [namespace_of(n) for n in ('', '/', 'train1', '/a/b/')] == ['/', '/', '/train1',
                                                                       '/a/b']
    with pytest.raises(ConfigError, match='--namespace'):
        namespace_of('train 1')


# ---------------------------------------------------------------------------- railgsa run
def start_run(tmp_path: Path, *args: str) -> tuple[subprocess.Popen, Path]:
    log = tmp_path / f'run-{time.monotonic_ns()}.log'
    with log.open('w') as out:
        proc = subprocess.Popen([sys.executable, '-m', 'railgsa_ros.cli.main', 'run', *args],
                                stdout=out, stderr=subprocess.STDOUT, cwd=tmp_path)
    return proc, log


def startup_lines(log: Path) -> dict[str, list[str]]:
    """Node -> its INFO lines (the nodes' output goes to railgsa run's own)."""
    lines = log.read_text().splitlines()
    return {n: [ln for ln in lines if f'[train1.{n}]' in ln or f'[{n}]' in ln] for n in NODES}


@pytest.mark.ros
def test_run_starts_both_nodes_from_one_file_and_forwards_sigterm(tmp_path: Path,
                                                                  wait_for: Any) -> None:
    params = write(tmp_path, '/**:\n  ros__parameters:\n    band: d2\n    method: kalman\n'
                             '/**/uncertainty_node:\n  ros__parameters:\n    rule: pem3\n'
                             '    order: 1\n')
    proc, log = start_run(tmp_path, '--params', str(params), '--namespace', 'train1')
    try:
        assert wait_for(lambda: all(startup_lines(log).values()) or proc.poll() is not None,
                        90.0), log.read_text()
        time.sleep(0.5)  # nothing more is logged at start-up
        lines = startup_lines(log)
        assert [len(lines[n]) for n in NODES] == [1, 1], lines
        for node, outputs in zip(NODES, ('/train1/track/irregularity, /diagnostics',
                                         '/train1/track/irregularity_band, /train1/track/'
                                         'sensitivity, /diagnostics'), strict=True):
            line = lines[node][0]
            assert 'kalman, band d2' in line, line
            assert f'/train1/imu/data, /train1/odom -> {outputs}' in line, line
        assert '(pem3, order 1,' in lines['uncertainty_node'][0]
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert 'Traceback' not in log.read_text()


@pytest.mark.ros
def test_run_exits_non_zero_when_a_node_dies(tmp_path: Path, wait_for: Any) -> None:
    proc, log = start_run(tmp_path)
    try:
        assert wait_for(lambda: startup_lines(log)['uncertainty_node'] or
                        proc.poll() is not None, 90.0), log.read_text()
        children = Path(f'/proc/{proc.pid}/task/{proc.pid}/children').read_text().split()
        victim = next(int(pid) for pid in children
                      if b'uncertainty_node' in Path(f'/proc/{pid}/cmdline').read_bytes())
        subprocess.run(['kill', '-KILL', str(victim)], check=True)
        rc = proc.wait(60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc != 0
    assert re.search(r'^error: uncertainty_node exited with code -9: stopped the others$',
                     log.read_text(), re.MULTILINE), log.read_text()


# ---------------------------------------------------------------------------- the launch file
def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call)
            and getattr(n.func, 'id', getattr(n.func, 'attr', None)) == name]


def _kw(call: ast.Call) -> dict[str, ast.expr]:
    return {k.arg: k.value for k in call.keywords}


def test_launch_file_starts_both_nodes_from_one_params_file(monkeypatch: Any) -> None:
    from test_packaging import setup_kwargs

    tree = ast.parse(LAUNCH.read_text())
    assert any(isinstance(n, ast.FunctionDef) and n.name == 'generate_launch_description'
               for n in tree.body)
    consts = {n.targets[0].id: n.value for n in tree.body if isinstance(n, ast.Assign)}
    assert ast.literal_eval(consts['PACKAGE']) == 'railgsa_ros'
    # variables bound to launch arguments: name -> argument
    bound = {n.targets[0].id: ast.literal_eval(n.value.args[0])
             for n in ast.walk(tree) if isinstance(n, ast.Assign)
             and isinstance(n.value, ast.Call) and getattr(n.value.func, 'id', '') ==
             'LaunchConfiguration'}
    declared = {ast.literal_eval(c.args[0]): c for c in _calls(tree, 'DeclareLaunchArgument')}
    assert set(declared) == {'params_file', 'namespace', 'record', 'record_out'}
    default = _kw(declared['params_file'])['default_value']
    parts = [ast.literal_eval(e) for e in default.args[0].elts[1:]]
    assert parts == ['config', 'railgsa.yaml'] and (REPO / 'config' / 'railgsa.yaml').is_file()
    nodes = {ast.literal_eval(_kw(c)['executable']): _kw(c) for c in _calls(tree, 'Node')}
    assert set(nodes) == {'irregularity_node', 'uncertainty_node', 'recorder'}
    for kw in nodes.values():
        assert kw['package'].id == 'PACKAGE' and bound[kw['namespace'].id] == 'namespace'
        assert 'name' not in kw  # a __node remap would rename uncertainty_node's helper too
    given = [[e.id for e in nodes[n]['parameters'].elts] for n in NODES]
    assert given[0] == given[1] and len(given[0]) == 1 and bound[given[0][0]] == 'params_file'
    assert 'condition' in nodes['recorder'] and 'IfCondition' in ast.dump(
        nodes['recorder']['condition'])
    kwargs = setup_kwargs(monkeypatch)
    data = dict(kwargs['data_files'])
    assert data['share/railgsa_ros/launch'] == ['launch/railgsa.launch.py']
    assert 'config/railgsa.yaml' in data['share/railgsa_ros/config']
    scripts = {s.split('=')[0].strip() for s in kwargs['entry_points']['console_scripts']}
    assert set(nodes) <= scripts  # ros2 run / launch find them in lib/railgsa_ros
