"""The default germ follows the input distributions (Wiener-Askey), issue 12 item 7."""

from __future__ import annotations

import numpy as np
import pytest

from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uncertainty.surrogate import build_design
from railgsa_ros.uq import Normal, Uniform, analyze
from railgsa_ros.uq.germ import default_germ
from railgsa_ros.vehicle import VehicleParams

# Ishigami (a = 7, b = 0.1): closed-form indices
ISHIGAMI_S1 = np.array([0.3139, 0.4424, 0.0])
ISHIGAMI_ST = np.array([0.5576, 0.4424, 0.2437])


def ishigami(x):
    return np.sin(x[:, 0]) + 7 * np.sin(x[:, 1]) ** 2 + 0.1 * x[:, 2] ** 4 * np.sin(x[:, 0])


def test_uniform_inputs_get_legendre_by_default_and_its_accuracy():
    dists = [Uniform(-np.pi, np.pi)] * 3
    auto = analyze(ishigami, dists, order=8, rule='gauss', delta=False, n_mc=1024)
    hermite = analyze(ishigami, dists, order=8, rule='gauss', delta=False, n_mc=1024,
                      germ='hermite')
    assert auto.pce.germ == 'legendre'
    err_auto = np.max(np.abs(auto.sobol_total - ISHIGAMI_ST))
    err_hermite = np.max(np.abs(hermite.sobol_total - ISHIGAMI_ST))
    assert err_auto < 0.01 and np.max(np.abs(auto.sobol_first - ISHIGAMI_S1)) < 0.01
    assert err_hermite > 0.05  # the old default on uniform inputs


def test_normal_inputs_unchanged_by_the_new_default():
    dists = [Normal(2.0, 0.3), Normal(1.0, 0.2, lower=0.0)]

    def model(x):
        return np.exp(0.3 * x[:, 0]) * x[:, 1] + x[:, 1] ** 2

    auto = analyze(model, dists, order=2, delta=False, n_mc=1024)
    hermite = analyze(model, dists, order=2, delta=False, n_mc=1024, germ='hermite')
    assert auto.pce.germ == 'hermite'
    np.testing.assert_array_equal(auto.pce.coef, hermite.pce.coef)
    np.testing.assert_array_equal(auto.samples, hermite.samples)


@pytest.mark.parametrize(('dists', 'rule', 'germ'), [
    ([Uniform(0, 1), Uniform(1, 2)], 'lstsq', 'legendre'),
    ([Uniform(0, 1), Uniform(1, 2)], 'pem5', 'hermite'),  # PEM rules exist for Hermite only
    ([Uniform(0, 1), Normal(1, 0.1)], 'gauss', 'hermite'),  # mixed: documented choice
    ([Normal(1, 0.1)], 'gauss', 'hermite')])
def test_default_germ_rules(dists, rule, germ):
    assert default_germ(dists, rule) == germ


def test_uncertainty_design_resolves_auto():
    nominal = VehicleParams()
    dists = {'k_s': Uniform(0.8 * nominal.k_s, 1.2 * nominal.k_s),
             'c': Uniform(0.8 * nominal.c, 1.2 * nominal.c)}
    assert build_design(UncertaintyConfig(), nominal, dists).germ == 'hermite'  # pem5
    gauss = UncertaintyConfig(rule='gauss', order=3)
    assert build_design(gauss, nominal, dists).germ == 'legendre'
    assert build_design(gauss.with_(germ='hermite'), nominal, dists).germ == 'hermite'
