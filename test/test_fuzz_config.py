"""Property-based fuzzing of the configuration loaders and the CLI's handling of bad files.

Any bytes, any YAML text and any YAML document (wrong types, missing and unknown keys, nested
garbage, numeric strings, NaN, inf, subnormals, huge numbers) give either a valid result or a
ConfigError whose message is one line that starts with the file name; never another exception.
Accepted values are checked against an independent oracle where one fits (vehicle) and against
the declared types and bounds otherwise. The CLI turns every such file into exit code 2 and one
``error: <file>: ...`` line.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields
import math
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
import pytest
import yaml

from railgsa_ros.cli.main import main as railgsa
from railgsa_ros.config import load_yaml
from railgsa_ros.errors import ConfigError
from railgsa_ros.imu import load_imu
from railgsa_ros.inverse import config as inverse_config
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.uncertainty import config as uncertainty_config
from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uncertainty.parameters import load_uncertainty
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import PARAM_BOUNDS, PARAM_NAMES, VehicleParams, load_vehicle

FUZZ = settings(max_examples=120, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])

NUMERIC_STRINGS = ('2.13e6', '2.13e+6', '1e400', '-1e-320', 'nan', '-inf', '.inf', '0x1F',
                   '1_000', ' 7 ', 'true', '', '~', '5e-324', '1e308')
scalars = st.one_of(
    st.none(), st.booleans(),
    st.integers(-10**20, 10**20), st.sampled_from([2**63, -2**63 - 1, 10**309, -10**400]),
    st.floats(),  # NaN, +-inf, subnormals, 1e308 included
    st.text(max_size=12), st.sampled_from(NUMERIC_STRINGS))
keys = st.one_of(st.text(max_size=10), st.integers(-5, 5), st.none(), st.booleans(),
                 st.sampled_from(['a\nb', 'x\u2028y', '\x00']))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=3)
                      | st.dictionaries(keys, inner, max_size=3), max_leaves=8)
#: raw files: arbitrary bytes (mostly not UTF-8), arbitrary text, YAML that PyYAML rejects
#: or lets escape as ValueError/RecursionError, and dumped documents
DEEP = '[' * 600 + ']' * 600  # beyond the recursion limit of PyYAML's composer
TRICKY = ('a: 2020-13-45', 'a: ' + '9' * 5000, DEEP, 'a: !!int 0x',
          'a: !!python/object:os.system x', 'a: &x [*x]', '---\na: 1\n---\nb: 2', 'a:\tb',
          'a: [1, 2', '{a: 1, a: 2}', '\ufeffvehicle: {}', 'a: !!binary xx', 'a: !!set {1}')
raw_files = st.one_of(st.binary(max_size=200), st.text(max_size=200), st.sampled_from(TRICKY),
                      values.map(lambda v: yaml.safe_dump(v, allow_unicode=True)))


@pytest.fixture(scope='module')
def path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One file, rewritten by every example."""
    return tmp_path_factory.mktemp('fuzz') / 'config.yaml'


def write(path: Path, content: Any) -> None:
    """Bytes as they are, text as UTF-8, anything else dumped as YAML."""
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif isinstance(content, str):
        path.write_text(content, encoding='utf-8')
    else:
        path.write_text(yaml.safe_dump(content, allow_unicode=True), encoding='utf-8')


def outcome(load: Callable[[Path], Any], path: Path) -> Any:
    """The loader's result, or its ConfigError after checking the message: one line that
    names the file."""
    try:
        return load(path)
    except ConfigError as exc:
        message = str(exc)
        assert len(message.splitlines()) == 1, message
        assert message.startswith(f'{path}: '), message
        return exc


def positive_number(value: Any) -> float | None:
    """Oracle of a vehicle field: a positive finite float from a number or numeric string."""
    if isinstance(value, bool):
        return None
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            return None
    if not isinstance(value, (int, float)):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) and number > 0 else None


# ---------------------------------------------------------------------------- load_yaml, imu
@FUZZ
@given(raw_files)
def test_load_yaml_returns_a_document_or_a_one_line_config_error(path: Path,
                                                                 content: Any) -> None:
    write(path, content)
    outcome(load_yaml, path)


def test_load_yaml_errors_name_file_and_cause(path: Path) -> None:
    cases = {'a: 2020-13-45': 'invalid YAML value (month must be in 1..12)',
             DEEP: 'invalid YAML (nested too deeply)',
             'a: [1, 2': 'invalid YAML (line 1)', b'\xff\xfe\x00': 'not a UTF-8 text file'}
    for content, reason in cases.items():
        write(path, content)
        with pytest.raises(ConfigError) as info:
            load_yaml(path)
        assert str(info.value) == f'{path}: {reason}'
    with pytest.raises(ConfigError, match='not a regular file'):
        load_yaml(path.parent)  # a directory
    with pytest.raises(ConfigError, match='cannot read'):
        load_yaml(path.parent / 'missing.yaml')


# ---------------------------------------------------------------------------- vehicle
vehicle_sections = st.tuples(
    st.fixed_dictionaries({n: st.one_of(st.floats(1.0, 1e9), st.integers(1, 10**9), values)
                           for n in PARAM_NAMES}, optional={'mass': values, 7: values}),
    st.sets(st.sampled_from(PARAM_NAMES), max_size=2),
).map(lambda t: {k: v for k, v in t[0].items() if k not in t[1]})


@FUZZ
@given(st.one_of(vehicle_sections.map(lambda s: {'vehicle': s}), values, raw_files))
def test_load_vehicle_matches_the_oracle(path: Path, doc: Any) -> None:
    write(path, doc)
    result = outcome(load_vehicle, path)
    section = doc.get('vehicle') if isinstance(doc, dict) else None
    if not isinstance(section, dict) or set(section) != set(PARAM_NAMES):
        assert isinstance(result, ConfigError) or isinstance(doc, (str, bytes))
        return
    want = {n: positive_number(section[n]) for n in PARAM_NAMES}
    bad = [n for n in PARAM_NAMES if want[n] is None or
           not PARAM_BOUNDS[n][0] <= want[n] <= PARAM_BOUNDS[n][1]]
    if bad:
        assert isinstance(result, ConfigError) and f'vehicle.{bad[0]}:' in str(result)
    else:
        assert result == VehicleParams(**want)


# ---------------------------------------------------------------------------- node configs
def garbage_for(config_cls: type) -> st.SearchStrategy:
    """{field: value} with a few fields of ``config_cls`` (and unknown names) set to anything."""
    names = [f.name for f in fields(config_cls) if f.name != 'inversion']
    return st.dictionaries(st.one_of(st.sampled_from(names), keys), values, max_size=4)


def assert_valid(config: Any, given_values: dict) -> None:
    """Every numeric field of a loaded config is finite, of its default's type and in bounds;
    given strings and booleans are kept as given."""
    for f in fields(config):
        if f.name == 'inversion':
            assert_valid(config.inversion, given_values)
            continue
        value = getattr(config, f.name)
        assert type(value) is type(f.default), (f.name, value)
        if isinstance(value, (bool, str)):
            assert value == given_values.get(f.name, f.default)
        elif f.metadata['bounds'] is not None:
            low, high = f.metadata['bounds']
            assert math.isfinite(value) and low <= value <= high, (f.name, value)


def config_case(node: str, load: Callable, config_cls: type, path: Path,
                params: dict) -> None:
    """Write ``params`` as ``node: ros__parameters:``, load, check the outcome."""
    write(path, {node: {'ros__parameters': params}})
    result = outcome(load, path)
    known = {f.name for f in fields(config_cls)} | {f.name for f in fields(InversionConfig)}
    given_known = {k: v for k, v in params.items() if k in known}
    if isinstance(result, ConfigError):  # the defaults are valid: a given field is to blame
        not_names = [k for k in params if not (isinstance(k, str) and k and k.isprintable())]
        assert any(isinstance(k, str) and k in str(result) for k in given_known) or \
            (not_names and str(result).endswith('is not a name')), str(result)
    else:
        assert_valid(result, given_known)


@FUZZ
@given(garbage_for(InversionConfig))
def test_inversion_load_config(path: Path, params: dict) -> None:
    config_case(inverse_config.NODE_NAME, inverse_config.load_config, InversionConfig, path,
                params)


@FUZZ
@given(st.one_of(garbage_for(UncertaintyConfig), garbage_for(InversionConfig)))
def test_uncertainty_load_config(path: Path, params: dict) -> None:
    config_case(uncertainty_config.NODE_NAME, uncertainty_config.load_config,
                UncertaintyConfig, path, params)


@FUZZ
@given(st.one_of(garbage_for(InversionConfig), garbage_for(UncertaintyConfig)))
def test_from_mapping_unknown_and_bad_names_give_one_line(params: dict) -> None:
    for cls in (InversionConfig, UncertaintyConfig):
        try:
            cls.from_mapping(params, source='params')
        except ConfigError as exc:
            assert len(str(exc).splitlines()) == 1 and str(exc).startswith('params: ')


def test_from_mapping_names_odd_keys_on_one_line() -> None:
    with pytest.raises(ConfigError) as info:
        InversionConfig.from_mapping({'a\nb': 1, 3: 1, None: 2, 'zeta': 0}, source='p.yaml')
    assert str(info.value) == \
        'p.yaml: unknown parameter(s) 3, None, zeta, 1 more key that is not a name'
    beyond = 'expected a finite number, got an integer beyond the float range'
    with pytest.raises(ConfigError, match=f'^parameters: gain: {beyond}$'):
        InversionConfig.from_mapping({'gain': 10**400})
    with pytest.raises(ConfigError, match=f'^parameters: germ_samples: {beyond}$'):
        UncertaintyConfig.from_mapping({'germ_samples': 10**400})


# ---------------------------------------------------------------------------- uncertainty file
DISTS = {'normal': ('mu', 'sigma', 'lower', 'upper'), 'uniform': ('a', 'b'),
         'lognormal': ('mu', 'sigma'), 'gamma': ('shape', 'scale'), 'exponential': ('rate',),
         'empirical': ('samples',)}
dist_specs = st.sampled_from(sorted(DISTS)).flatmap(lambda d: st.fixed_dictionaries(
    {'dist': st.just(d)}, optional={**{f: st.one_of(st.floats(-1e6, 1e7), values)
                                       for f in DISTS[d]}, 'extra': values}))
uncertainty_docs = st.dictionaries(st.one_of(st.sampled_from(PARAM_NAMES), keys),
                                   st.one_of(dist_specs, values), max_size=3)


@FUZZ
@given(st.one_of(uncertainty_docs.map(lambda p: {'parameters': p}), values, raw_files))
def test_load_uncertainty(path: Path, doc: Any) -> None:
    write(path, doc)
    result = outcome(load_uncertainty, path)
    if isinstance(result, ConfigError):
        return
    params = doc['parameters']
    assert list(result) == [n for n in PARAM_NAMES if n in params]
    for name, dist in result.items():
        assert isinstance(dist, Distribution)
        assert dist.from_xi(-40.0) >= 0.0, name  # positive physical parameters only


# ---------------------------------------------------------------------------- imu (foundation)
def printable_keys(doc: dict) -> bool:
    return all(isinstance(k, str) and k.isprintable() for k in doc['imu'])


@FUZZ
@given(st.dictionaries(st.one_of(st.sampled_from(
    ['preset', 'noise_density', 'output_rate_hz', 'bias', 'range_mps2']), st.text(max_size=8)),
    values, max_size=3).map(lambda s: {'imu': s}).filter(printable_keys) | raw_files)
def test_load_imu(path: Path, doc: Any) -> None:
    write(path, doc)
    outcome(load_imu, path)


@pytest.mark.parametrize('section', [{0: None}, {'\x85 ': None}])
def test_load_imu_odd_keys(path: Path, section: dict) -> None:
    write(path, {'imu': section})
    assert isinstance(outcome(load_imu, path), ConfigError)


# ---------------------------------------------------------------------------- the CLI
@settings(FUZZ, max_examples=40)
@given(st.one_of(values, raw_files, vehicle_sections.map(lambda s: {'vehicle': s}),
                 uncertainty_docs.map(lambda p: {'parameters': p})))
def test_cli_bad_files_exit_2_with_one_line(path: Path, capsys: pytest.CaptureFixture,
                                            doc: Any) -> None:
    write(path, doc)
    assume(isinstance(outcome(load_vehicle, path), ConfigError))
    assume(isinstance(outcome(load_uncertainty, path), ConfigError))
    out = path.parent / 'bode.png'
    for argv in (['bode', '--vehicle', str(path), '--out', str(out)],
                 ['gsa', '--uncertainty', str(path), '--time', '1']):
        capsys.readouterr()
        assert railgsa(argv) == 2
        captured = capsys.readouterr()
        assert captured.out == '' and not out.exists()
        assert captured.err.startswith(f'error: {path}: ') and captured.err.count('\n') == 1
