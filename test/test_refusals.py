"""Refuse instead of guessing or crashing: vehicle bounds in every entry point, ``gsa``
arguments, an output that is (or is inside, or contains) an input."""

import os
from pathlib import Path
import re
import resource
import subprocess
import sys

import numpy as np
import pytest

from railgsa_ros.cli.main import main
from railgsa_ros.errors import ConfigError
from railgsa_ros.fileio import refuse_overlap
from railgsa_ros.vehicle import PARAM_BOUNDS, PARAM_NAMES, PARAM_UNITS, VehicleParams

FAST_GSA = ['gsa', '--rule', 'pem3', '--order', '1']


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('error: ') and 'Traceback' not in err, err
    return err


@pytest.fixture
def bag(short_bag: Path) -> Path:
    return short_bag


def vehicle_file(tmp_path: Path, **values: float) -> Path:
    fields = {**VehicleParams().as_dict(), **values}
    path = tmp_path / 'vehicle.yaml'
    path.write_text('vehicle:\n' + ''.join(f'  {k}: {v!r}\n' for k, v in fields.items()))
    return path


# ---------------------------------------------------------------------------- vehicle bounds
@pytest.mark.parametrize('name', PARAM_NAMES)
def test_vehicle_bounds_are_inclusive_and_named(name) -> None:
    low, high = PARAM_BOUNDS[name]
    assert low < VehicleParams().as_dict()[name] < high  # Table 1 inside
    for edge in (low, high):
        assert getattr(VehicleParams(**{name: edge}), name) == edge
    for outside in (low * 0.999, high * 1.001, 1e300):
        unit = re.escape(PARAM_UNITS[name])
        with pytest.raises(ConfigError, match=rf'^vehicle.{name}: .* {unit} is outside the '
                                              r'physical range \['):
            VehicleParams(**{name: outside})


def test_node_parameter_bounds_are_the_vehicle_bounds(have_rclpy) -> None:
    if not have_rclpy:
        pytest.skip('rclpy not installed')
    from railgsa_ros.nodes.specs import VEHICLE_SPECS

    assert {s.name: s.bounds for s in VEHICLE_SPECS} == PARAM_BOUNDS


@pytest.mark.parametrize('command', ['invert', 'gsa', 'review', 'bode'])
def test_extreme_vehicle_refused_by_every_command(bag, tmp_path, capsys, command) -> None:
    """m_s 1e300 made NaN output and a Kalman traceback: now one line naming file and field."""
    vehicle = vehicle_file(tmp_path, m_s=1e300)
    args = {'invert': ['invert', str(bag), '--csv', str(tmp_path / 'u.csv'), '--method',
                       'kalman'],
            'gsa': FAST_GSA, 'review': ['review', str(bag), '--out', str(tmp_path / 'r'),
                                        '--no-progress'],
            'bode': ['bode', '--out', str(tmp_path / 'b.png')]}[command]
    assert main([*args, '--vehicle', str(vehicle)]) == 2
    assert one_error_line(capsys) == (f'error: {vehicle}: vehicle.m_s: 1e+300 kg is outside the '
                                      'physical range [100, 100000] kg\n')
    assert not any(p.name != 'vehicle.yaml' for p in tmp_path.iterdir())


@pytest.mark.parametrize(('spec', 'message'), [
    ('m_s: {dist: normal, mu: 1.0e+300, sigma: 1.0e+299}',
     'parameters.m_s: median 1e+300 kg is outside the physical range [100, 100000] kg'),
    ('k_s: {dist: uniform, a: 1.0, b: 2.0}',
     'parameters.k_s: median 1.5 N/m is outside the physical range [10000, 1e+08] N/m'),
])
def test_uncertain_parameters_outside_the_vehicle_bounds_are_refused(tmp_path, capsys, spec,
                                                                     message) -> None:
    """An uncertainty file centred on 1e300 kg gave a plausible-looking gsa result."""
    path = tmp_path / 'u.yaml'
    path.write_text(f'parameters:\n  {spec}\n')
    assert main([*FAST_GSA, '--uncertainty', str(path)]) == 2
    assert one_error_line(capsys) == f'error: {path}: {message}\n'


def test_kalman_without_a_steady_state_filter_is_one_line(bag, tmp_path, capsys) -> None:
    """A corner of the bounds (100 kg body on a 1e8 N/m spring, 10 kg wheel, c = 100) has no
    DARE solution: one line that names the method; the spectral method still works."""
    vehicle = vehicle_file(tmp_path, m_s=100.0, m_us=10.0, k_s=1e8, k_us=1e6, c=100.0)
    out = tmp_path / 'u.csv'
    assert main(['invert', str(bag), '--csv', str(out), '--method', 'kalman', '--vehicle',
                 str(vehicle)]) == 2
    assert one_error_line(capsys).startswith('error: method kalman: no steady-state filter')
    assert main(['invert', str(bag), '--csv', str(out), '--vehicle', str(vehicle)]) == 0
    data = np.loadtxt(out, delimiter=',', skiprows=1)  # t_s, chainage_m, u_m, quality
    assert np.isfinite(data[:, [0, 1, 3]]).all()
    # u is NaN exactly where the policy marks the output INVALID (2), never from a blow-up
    np.testing.assert_array_equal(np.isnan(data[:, 2]), data[:, 3] == 2)


# ---------------------------------------------------------------------------- gsa arguments
@pytest.mark.parametrize(('args', 'message'), [
    (['--time', '1e9'], 'error: time: 1e+09 s is beyond the longest scenario (120 s at 2000 Hz)'),
    (['--validate', '-1'], 'error: --validate: expected a number of base samples >= 2, got -1'),
    (['--validate', '0'], 'error: --validate: expected a number of base samples >= 2, got 0'),
    (['--seed', '-1'], 'error: --seed: expected an integer >= 0, got -1'),
    (['--order', '40'], 'error: order: expected an integer in [1, 10], got 40'),
    (['--time', 'nan'], 'error: time: nan s is not a sample time'),
])
def test_gsa_arguments_refused_with_one_line(capsys, args, message) -> None:
    assert main([*FAST_GSA, *args]) == 2
    assert one_error_line(capsys).startswith(message)


def test_gsa_plot_into_a_read_only_place_fails_before_the_analysis(tmp_path, capsys) -> None:
    ro = tmp_path / 'ro'
    ro.mkdir()
    ro.chmod(0o555)
    place = ro if not os.access(ro, os.W_OK) else Path('/sys/fs')  # root: a read-only fs
    assert main([*FAST_GSA, '--plot', str(place / 'plots')]) == 2
    assert one_error_line(capsys).startswith(f'error: {place / "plots"}: cannot write (')
    file = tmp_path / 'file'
    file.write_text('x')
    assert main([*FAST_GSA, '--plot', str(file)]) == 2
    assert one_error_line(capsys).startswith(f'error: {file}: cannot write (')


def test_gsa_plot_on_a_full_disk_is_one_line_and_leaves_no_partial_file(tmp_path) -> None:
    """A 8 kB file-size limit (as a full disk): the first PNG cannot be written."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))

    out = tmp_path / 'plots'
    proc = subprocess.run([sys.executable, '-m', 'railgsa_ros.cli.main', *FAST_GSA, '--plot',
                           str(out)], capture_output=True, text=True, preexec_fn=limit,
                          timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == f'error: {out / "histogram.png"}: cannot write (File too large)\n'
    assert list(out.iterdir()) == []


# ---------------------------------------------------------------------------- output vs input
def test_refuse_overlap_resolves_paths(tmp_path) -> None:
    data = tmp_path / 'bag'
    data.mkdir()
    (tmp_path / 'link').symlink_to(data)
    for out, relation in ((data, 'is'), (tmp_path / 'link', 'is'), (data / 'x.csv', 'is inside'),
                          (tmp_path / 'link' / 'sub' / 'x', 'is inside'), (tmp_path, 'contains'),
                          (data / '..' / 'bag', 'is')):
        with pytest.raises(ConfigError, match=f'the output {relation} the input'):
            refuse_overlap(out, [None, data])
    refuse_overlap(tmp_path / 'bag2', [data, None, ''])  # a sibling with a common prefix
    refuse_overlap(tmp_path / 'other' / 'x.csv', [data])


@pytest.mark.parametrize('overwrite', [False, True])
@pytest.mark.parametrize('where', ['the bag', 'inside', 'a parent'])
def test_invert_and_review_never_write_onto_their_input(bag, tmp_path, capsys, overwrite,
                                                        where) -> None:
    """Before: ``--overwrite`` with the output equal to the input destroyed the bag."""
    before = {p: p.read_bytes() for p in bag.iterdir()}
    out = {'the bag': bag, 'inside': bag / 'out', 'a parent': bag.parent}[where]
    flag = ['--overwrite'] if overwrite else []
    for args in (['invert', str(bag), '--csv', str(out), *flag],
                 ['invert', str(bag), '--out', str(out), *flag],
                 ['review', str(bag), '--out', str(out), '--no-progress', *flag]):
        assert main(args) == 2
        assert 'the input' in one_error_line(capsys)
    assert {p: p.read_bytes() for p in bag.iterdir()} == before


def test_simulate_and_bode_never_write_onto_their_input(tmp_path, capsys) -> None:
    vehicle = vehicle_file(tmp_path)
    assert main(['simulate', '--out', str(vehicle), '--vehicle', str(vehicle), '--duration',
                 '1', '--overwrite']) == 2
    assert 'the output is the input' in one_error_line(capsys)
    assert main(['bode', '--out', str(vehicle), '--vehicle', str(vehicle)]) == 2
    assert 'the output is the input' in one_error_line(capsys)
    assert VehicleParams() == VehicleParams(**{
        k: float(v) for k, v in (line.strip().split(': ') for line in
                                 vehicle.read_text().splitlines()[1:])})


def test_fleet_never_writes_onto_its_input(bag, tmp_path, capsys) -> None:
    pytest.importorskip('duckdb')
    assert main(['fleet', 'ingest', str(bag), '--db', str(bag / 'fleet.duckdb')]) == 2
    assert 'the output is inside the input' in one_error_line(capsys)
    db = tmp_path / 'fleet.duckdb'
    assert main(['fleet', 'report', '--db', str(db), '--out', str(db), '--overwrite']) == 2
    assert 'the output is the input' in one_error_line(capsys)
    assert not (bag / 'fleet.duckdb').exists() and not db.exists()
