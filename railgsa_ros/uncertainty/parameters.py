"""Uncertain vehicle parameters from YAML (``--uncertainty``) and the paper's Table 3 default.

Schema::

    parameters:
      k_s: {dist: normal, mu: 2.13e+6, sigma: 7.1e+5}   # optional lower/upper, default lower: 0
      c: {dist: uniform, a: 8.0e+4, b: 1.6e+5}
    discrepancy_std_m: 4.0e-5   # optional, m: model discrepancy (``railgsa calibrate``), default 0

Any of the vehicle model's ``param_names`` (the quarter car: m_s, m_us, k_s, k_us, c; the coach:
m_c, J_c, m_b, J_b, m_w, k_p, c_p, k_s, c_s, k_h; ``config/uncertainty_coach.yaml``), each median
within the model's ``bounds``. Distributions: normal (mu, sigma, lower, upper), uniform (a, b),
lognormal (mu, sigma of ln x), gamma (shape, scale), exponential (rate), empirical (samples).
Negative-sample policy: every parameter is positive, so a normal is truncated at ``lower``
(default 0) and uniform/empirical values must be positive.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from railgsa_ros.config import key_list, load_yaml
from railgsa_ros.errors import ConfigError
from railgsa_ros.models import VehicleModel, as_model
from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uq.distributions import (
    Distribution,
    Empirical,
    Exponential,
    Gamma,
    LogNormal,
    Normal,
    Uniform,
)
from railgsa_ros.vehicle import VehicleParams

FIELDS = {'normal': (Normal, ('mu', 'sigma'), ('lower', 'upper')),
          'uniform': (Uniform, ('a', 'b'), ()),
          'lognormal': (LogNormal, ('mu', 'sigma'), ()),
          'gamma': (Gamma, ('shape', 'scale'), ()),
          'exponential': (Exponential, ('rate',), ()),
          'empirical': (Empirical, ('samples',), ())}
TABLE_3 = ('k_s', 'k_us', 'c')  # uncertain in the paper, sigma = mu / 3


def table3(vehicle: VehicleParams | VehicleModel | None = None) -> dict[str, Distribution]:
    """The paper's Table 3: k_s, k_us, c ~ Normal(mu = nominal, sigma = mu / 3), truncated at 0,
    around the quarter car ``vehicle`` (VehicleParams or its model); ConfigError for a model
    without those parameters (a coach: its law is a file, ``config/uncertainty_coach.yaml``)."""
    model = as_model(vehicle)
    missing = [n for n in TABLE_3 if n not in model.param_names]
    if missing:
        raise ConfigError(f'uncertainty: the paper\'s Table 3 is for the quarter car; the '
                          f'{model.kind} has no {", ".join(missing)}: give an uncertainty file')
    nominal = dict(zip(model.param_names, model.theta.tolist(), strict=True))
    return {name: Normal(nominal[name], nominal[name] / 3.0, lower=0.0) for name in TABLE_3}


def _number(value: Any) -> Any:
    """YAML 1.1 leaves '2.13e6' a string: accept numeric strings."""
    try:
        return float(value) if isinstance(value, str) else value
    except ValueError:
        return value


def parse_parameter(name: str, spec: Any, model: VehicleModel | None = None) -> Distribution:
    """One entry of ``parameters:`` for a parameter of ``model`` (None: the quarter car);
    errors name ``parameters.<name>.<field>``."""
    model = as_model(model)
    where = f'parameters.{key_list([name])}'
    if name not in model.param_names:
        raise ConfigError(f'{where}: unknown parameter of the {model.kind}; expected any of '
                          f'{", ".join(model.param_names)}')
    dist_name = spec.get('dist') if isinstance(spec, dict) else None
    if not isinstance(dist_name, str) or dist_name not in FIELDS:
        raise ConfigError(f'{where}.dist: expected one of {", ".join(FIELDS)}')
    cls, required, optional = FIELDS[dist_name]
    unknown = set(spec) - {'dist', *required, *optional}
    missing = [f for f in required if f not in spec]
    if unknown or missing:
        field = key_list(unknown).split(', ')[0] if unknown else missing[0]
        raise ConfigError(f'{where}.{field}: {"unknown" if unknown else "missing"} field for '
                          f'dist {dist_name} (fields: {", ".join(required + optional)})')
    kwargs = {f: _number(spec[f]) for f in (*required, *optional) if f in spec}
    if cls is Normal:
        kwargs.setdefault('lower', 0.0)
    try:
        dist = cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f'{where}.{exc}') from None
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f'{where}: invalid values {kwargs!r}') from None
    low = dist.from_xi(-40.0)
    if not low >= 0.0:
        raise ConfigError(f'{where}: the distribution allows values below 0, but {name} is a '
                          f'positive physical parameter')
    median, (lowest, highest), unit = float(dist.from_xi(0.0)), model.bounds[name], \
        model.units[name]
    if not lowest <= median <= highest:  # the vehicle's physical bounds, as everywhere
        raise ConfigError(f'{where}: median {median:g} {unit} is outside the physical range '
                          f'[{lowest:g}, {highest:g}] {unit}')
    return dist


def load_uncertainty(path: str | Path | None, model: VehicleModel | None = None
                     ) -> dict[str, Distribution]:
    """Parameter name -> distribution for the parameters of ``model`` (None: the quarter car),
    in its ``param_names`` order; no path gives Table 3 (the quarter car only)."""
    model = as_model(model)
    if path is None:
        return table3(model)
    doc = load_yaml(path)
    params = doc.get('parameters') if isinstance(doc, dict) else None
    if not isinstance(params, dict) or not params:
        raise ConfigError(f'{path}: expected a non-empty "parameters:" mapping')
    try:
        parsed = {name: parse_parameter(name, spec, model) for name, spec in params.items()}
    except ConfigError as exc:
        raise ConfigError(f'{path}: {exc}') from None
    return {name: parsed[name] for name in model.param_names if name in parsed}


def load_discrepancy(path: str | Path) -> float:
    """The file's model-discrepancy std ``discrepancy_std_m`` (m, in [0, 1]); 0 when absent."""
    doc = load_yaml(path)
    value = _number(doc.get('discrepancy_std_m', 0.0)) if isinstance(doc, dict) else 0.0
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
        raise ConfigError(f'{path}: discrepancy_std_m: expected a std in [0, 1] m, got {value!r}')
    return float(value)


def with_discrepancy(config: UncertaintyConfig, path: str | Path | None) -> UncertaintyConfig:
    """``config`` with the uncertainty file's discrepancy where it is larger than the configured
    one (no file: unchanged), so that every entry point that reads the file adds it to the band."""
    if not path:
        return config
    return config.with_(discrepancy_std_m=max(config.discrepancy_std_m, load_discrepancy(path)))
