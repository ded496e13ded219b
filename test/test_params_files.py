"""Strict ROS params files: the shared loader (railgsa_ros.config.ros_parameters) and the
offline commands' ``--params`` (unknown keys, typos, a missing node section, vehicle keys)."""

from pathlib import Path

import numpy as np
import pytest

from railgsa_ros.bag import write_run
from railgsa_ros.cli.main import main
from railgsa_ros.config import ros_parameters
from railgsa_ros.errors import ConfigError
from railgsa_ros.scenario import run_scenario

KNOWN = ('method', 'gain', 'band')


def params(text: str, tmp_path: Path) -> Path:
    path = tmp_path / 'params.yaml'
    path.write_text(text)
    return path


@pytest.fixture
def bag(short_bag: Path) -> Path:
    return short_bag


# ---------------------------------------------------------------------------- the loader
def test_loader_merges_the_sections_that_apply_in_file_order() -> None:
    doc = {'/**': {'ros__parameters': {'gain': 1.0, 'band': 'd2', 'use_sim_time': True}},
           'other_node': {'ros__parameters': {'anything': 1}},
           '/ns/irregularity_node': {'ros__parameters': {'gain': 2.0}},
           'irregularity_node': {'ros__parameters': {'method': 'kalman'}}}
    assert ros_parameters(doc, 'irregularity_node', KNOWN, 'f.yaml') == {
        'gain': 2.0, 'band': 'd2', 'method': 'kalman'}


@pytest.mark.parametrize(('doc', 'message'), [
    ({'irregularity_node': {'ros__parameters': {'metod': 'kalman'}}},
     r'^f.yaml: irregularity_node: unknown parameter\(s\) metod \(did you mean method\?\)$'),
    ({'irregularity_nod': {'ros__parameters': {'method': 'kalman'}}},
     r'^f.yaml: no section for node irregularity_node .*\(sections: irregularity_nod\)$'),
    (None, r'^f.yaml: no section for node irregularity_node .*\(the file is empty\)$'),
    ([1, 2], r'^f.yaml: expected a ROS params file'),
    ({'irregularity_node': {'method': 'kalman'}},
     r'^f.yaml: section irregularity_node: expected only "ros__parameters:"'),
    ({'irregularity_node': {'ros__parameters': [1]}},
     r'^f.yaml: section irregularity_node: expected only "ros__parameters:"'),
    ({'irregularity_node': {'ros__parameters': {3: 1}}},
     r'^f.yaml: section irregularity_node: parameter name 3 is not a name$'),
    ({'irregularity_node': {'ros__parameters': {'m_s': 1.0}}},
     r'^f.yaml: irregularity_node: m_s: use a vehicle file$'),
])
def test_loader_refuses_with_one_line_naming_file_and_key(doc, message) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        ros_parameters(doc, 'irregularity_node', KNOWN, 'f.yaml',
                       refused={'m_s': 'use a vehicle file'})
    assert len(str(info.value).splitlines()) == 1


def test_loader_shared_section_accepts_other_nodes_names_but_not_typos() -> None:
    doc = {'/**': {'ros__parameters': {'gain': 3.0, 'rule': 'pem3'}}}
    assert ros_parameters(doc, 'irregularity_node', KNOWN, 'f.yaml',
                          shared_known={'rule'}) == {'gain': 3.0}
    doc['/**']['ros__parameters']['rulle'] = 'pem3'
    with pytest.raises(ConfigError, match=r'unknown parameter\(s\) rulle$'):
        ros_parameters(doc, 'irregularity_node', KNOWN, 'f.yaml', shared_known={'rule'})
    # a node section is checked against the node's own names only
    doc = {'irregularity_node': {'ros__parameters': {'rule': 'pem3'}}}
    with pytest.raises(ConfigError, match=r'unknown parameter\(s\) rule$'):
        ros_parameters(doc, 'irregularity_node', KNOWN, 'f.yaml', shared_known={'rule'})


def test_loader_optional_section() -> None:
    assert ros_parameters({'x': {'ros__parameters': {}}}, 'n', required=False) == {}


# ---------------------------------------------------------------------------- the commands
@pytest.mark.parametrize(('text', 'needle'), [
    ('irregularity_node:\n  ros__parameters:\n    metod: kalman\n',
     'metod (did you mean method?)'),
    ('irregularity_node:\n  ros__parameters:\n    speed_mp: 30.0\n', 'speed_mp'),
    ('irregularity_nod:\n  ros__parameters:\n    method: kalman\n',
     'no "irregularity_node:" section'),
    ('irregularity_node:\n  ros__parameters:\n    m_s: 5000.0\n', 'm_s: a vehicle parameter'),
    ('/**:\n  ros__parameters:\n    k_s: 1.0e+6\n', 'k_s: a vehicle parameter'),
    ('irregularity_node:\n  ros__parameters:\n    vehicle_file: v.yaml\n',
     'vehicle_file: a vehicle parameter'),
    ('irregularity_node:\n  ros__parameters:\n    use_odom: false\n', 'use_odom: a live-node'),
    ('', 'the file is empty'),
])
def test_invert_params_file_refused_naming_key_and_file(bag, tmp_path, capsys, text,
                                                         needle) -> None:
    path = params(text, tmp_path)
    out = tmp_path / 'u.csv'
    assert main(['invert', str(bag), '--csv', str(out), '--params', str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'error: {path}: ') and needle in err and err.count('\n') == 1, err
    assert not out.exists()


def test_review_params_file_refused_naming_key_and_file(bag, tmp_path, capsys) -> None:
    path = params('uncertainty_node:\n  ros__parameters:\n    rulle: pem3\n', tmp_path)
    assert main(['review', str(bag), '--out', str(tmp_path / 'r'), '--params', str(path),
                 '--no-progress']) == 2
    err = capsys.readouterr().err
    assert err == f'error: {path}: uncertainty_node: unknown parameter(s) rulle (did you mean ' \
                  'rule?)\n'
    path = params('irregularity:\n  ros__parameters:\n    method: kalman\n', tmp_path)
    assert main(['review', str(bag), '--out', str(tmp_path / 'r'), '--params', str(path),
                 '--no-progress']) == 2
    assert 'no "irregularity_node:" or "uncertainty_node:" section' in capsys.readouterr().err


def test_shared_file_applies_and_transport_keys_are_accepted(bag, tmp_path) -> None:
    """A file for both nodes under /** (uncertainty names, QoS depth, use_sim_time) gives the
    same CSV as the equivalent command-line option."""
    path = params('/**:\n  ros__parameters:\n    band: d2\n    rule: pem3\n'
                  '    output_qos_depth: 5000\n    use_sim_time: true\n'
                  'uncertainty_node:\n  ros__parameters:\n    order: 1\n', tmp_path)
    a, b = tmp_path / 'a.csv', tmp_path / 'b.csv'
    assert main(['invert', str(bag), '--csv', str(a), '--params', str(path)]) == 0
    assert main(['invert', str(bag), '--csv', str(b), '--band', 'd2']) == 0
    assert a.read_text() == b.read_text()
    c = tmp_path / 'c.csv'
    assert main(['invert', str(bag), '--csv', str(c)]) == 0  # d1: the file did change it
    assert not np.array_equal(np.loadtxt(a, delimiter=',', skiprows=1),
                              np.loadtxt(c, delimiter=',', skiprows=1))


def test_shipped_config_files_are_accepted(tmp_path) -> None:
    repo = Path(__file__).resolve().parents[1] / 'config'
    # 1 kHz: the rate_hz of config/irregularity.yaml (invert refuses a given rate_hz that
    # disagrees with the bag's)
    bag = write_run(tmp_path / 'run', run_scenario('german-low', 25.0, 3.0, 1000.0, 'adxl355',
                                                   seed=4))
    assert main(['invert', str(bag), '--csv', str(tmp_path / 'u.csv'), '--params',
                 str(repo / 'irregularity.yaml'), '--bands', '--uncertainty-params',
                 str(repo / 'uncertainty_node.yaml')]) == 0
