"""Scenarios, the uncertainty file and ``railgsa gsa``."""

import json

import numpy as np
import pytest

from railgsa_ros.cli.main import main
from railgsa_ros.errors import ConfigError
from railgsa_ros.simulate import simulate
from railgsa_ros.track import paper_profile
from railgsa_ros.uncertainty.parameters import load_uncertainty, table3
from railgsa_ros.uncertainty.scenarios import make_scenario, sample_indices
from railgsa_ros.uq import Normal, analyze
from railgsa_ros.vehicle import VehicleParams


def test_default_file_is_table_3():
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / 'config' / 'uncertainty.yaml'
    loaded, default = load_uncertainty(path), table3()
    assert list(loaded) == ['k_s', 'k_us', 'c'] == list(default)
    for name, dist in loaded.items():
        assert dist.mean() == pytest.approx(default[name].mean(), rel=1e-8)
        assert dist.from_xi(-40.0) >= 0.0  # truncated at 0: the negative-sample policy


@pytest.mark.parametrize(('text', 'field'), [
    ('parameters: {k_x: {dist: normal, mu: 1, sigma: 1}}', 'parameters.k_x'),
    ('parameters: {k_s: {dist: weibull}}', 'parameters.k_s.dist'),
    ('parameters: {k_s: {dist: normal, mu: 1}}', 'parameters.k_s.sigma'),
    ('parameters: {c: {dist: normal, mu: 1, sigma: -2}}', 'parameters.c.sigma'),
    ('parameters: {c: {dist: uniform, a: -1, b: 2}}', 'parameters.c'),
    ('parameters: {c: {dist: gamma, shape: 2, scale: 1, loc: 3}}', 'parameters.c.loc'),
    ('nothing: 1', 'parameters'),
])
def test_bad_uncertainty_file_names_the_field(tmp_path, text, field):
    path = tmp_path / 'u.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError, match=field.replace('.', r'\.')):
        load_uncertainty(path)


def test_yaml_numeric_strings_and_other_distributions(tmp_path):
    path = tmp_path / 'u.yaml'
    path.write_text('parameters:\n  k_s: {dist: normal, mu: 2.13e6, sigma: 7.1e5}\n'
                    '  m_s: {dist: uniform, a: 9000, b: 10000}\n'
                    '  c: {dist: lognormal, mu: 11.7, sigma: 0.1}\n')
    dists = load_uncertainty(path)
    assert list(dists) == ['m_s', 'k_s', 'c']
    assert dists['k_s'].mean() == pytest.approx(2.13e6, rel=2e-3)


def test_sample_times():
    assert sample_indices([7.0, 0.0], 5e-4).tolist() == [14000, 0]
    with pytest.raises(ConfigError, match='time'):
        sample_indices(7.00021, 5e-4)


def test_nominal_parameters_reconstruct_the_profile_and_forward_matches_simulate():
    dists = table3()
    nominal = VehicleParams()
    x = np.array([[nominal.k_s, nominal.k_us, nominal.c], [3e6, 1e8, 9e4]])
    inverse = make_scenario('inverse', [2.0, 7.0], dists)
    u = inverse(x)
    assert u.shape == (2, 2)
    np.testing.assert_allclose(u[0], paper_profile(np.array([20.0, 70.0])), atol=2e-6)
    assert abs(u[1, 1] - u[0, 1]) > 1e-5  # wrong parameters: a different reconstruction
    forward = make_scenario('forward', 7.0, dists)
    theta = forward.theta(x)
    a_s = simulate(forward.u, forward.dt, theta)[0][:, 14000]
    np.testing.assert_allclose(forward(x), a_s, rtol=1e-12)


def test_pem5_order_2_matches_high_order_gauss_for_small_uncertainty():
    # coefficient of variation 0.05: the response is nearly quadratic, PEM5 (19 runs) is exact
    nominal = VehicleParams()
    dists = {n: Normal(getattr(nominal, n), 0.05 * getattr(nominal, n), lower=0.0)
             for n in ('k_s', 'k_us', 'c')}
    model = make_scenario('inverse', 7.0, dists)
    pem = analyze(model, list(dists.values()), order=2, delta=False, n_mc=1024)
    ref = analyze(model, list(dists.values()), order=5, rule='gauss', delta=False, n_mc=1024)
    assert pem.n_evaluations == 19
    np.testing.assert_allclose(pem.sobol_total, ref.sobol_total, atol=0.01)
    assert pem.std == pytest.approx(ref.std, rel=0.01)


def test_cli_json_and_plots(tmp_path, capsys):
    assert main(['gsa', '--scenario', 'forward', '--time', '7', '--order', '2', '--json',
                 '--plot', str(tmp_path)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['n_evaluations'] == 19 and out['rule'] == 'pem5' and out['order'] == 2
    assert set(out['sobol_first']) == {'k_s', 'k_us', 'c'}
    assert out['quantiles']['2.5%'] < out['mean'] < out['quantiles']['97.5%']
    assert sum(out['sobol_first'].values()) <= 1.0 + 1e-9
    assert (tmp_path / 'histogram.png').stat().st_size > 1000
    assert (tmp_path / 'sensitivity.png').stat().st_size > 1000


def test_cli_bad_input_exits_2(tmp_path, capsys):
    assert main(['gsa', '--time', '7.00001']) == 2
    assert 'time' in capsys.readouterr().err
    bad = tmp_path / 'u.yaml'
    bad.write_text('parameters: {k_s: {dist: normal, mu: 1}}')
    assert main(['gsa', '--uncertainty', str(bad)]) == 2
    assert 'parameters.k_s.sigma' in capsys.readouterr().err


def test_cli_flat_output_has_undefined_indices(capsys):
    """At t = 0 the paper profile has not begun: the output's variance is rounding error and
    its shares are no sensitivities (they read 0.37 and 0.57): null with a note."""
    assert main(['gsa', '--time', '0', '--order', '2', '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['std'] < 1e-20
    for key in ('sobol_first', 'sobol_total', 'delta'):
        assert set(out[key].values()) == {None}
    assert any('undefined' in note for note in out['notes'])
