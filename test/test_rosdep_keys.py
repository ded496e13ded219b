"""Every dependency key of package.xml resolves for Jazzy's platforms in a recorded rosdistro
snapshot (test/data/rosdistro_keys.yaml, written by test/data/record_rosdistro.py from
ros/rosdistro): ``rosdep install --from-paths src`` does not stop on an unknown key."""

from __future__ import annotations

from pathlib import Path
from typing import Any
import xml.etree.ElementTree as ET

import yaml

REPO = Path(__file__).resolve().parents[1]
SNAPSHOT = yaml.safe_load((REPO / 'test' / 'data' / 'rosdistro_keys.yaml').read_text())
INSTALLERS = ('apt', 'pip')


def resolve(rule: Any, codename: str) -> tuple[str, list[str]] | None:
    """``(installer, packages)`` of one OS's rosdep rule for release ``codename``, as rosdep
    reads it: a list (the default installer, apt), ``{installer: [..]}`` or ``{installer:
    {packages: [..]}}``, optionally under a codename or ``'*'`` key; None when the rule is
    missing or null for that release."""
    if isinstance(rule, dict) and not set(rule) & set(INSTALLERS):
        rule = rule.get(codename, rule.get('*'))
    if isinstance(rule, list):
        return ('apt', rule) if rule else None
    if isinstance(rule, dict):
        installer = next(i for i in INSTALLERS if i in rule)
        packages = rule[installer]
        packages = packages.get('packages') if isinstance(packages, dict) else packages
        return (installer, packages) if packages else None
    return None


def package_keys() -> dict[str, str]:
    """Every ``<*depend>`` key of package.xml -> its tag."""
    root = ET.parse(REPO / 'package.xml').getroot()
    return {e.text: e.tag for e in root if e.tag.endswith('depend') and e.text}


def test_the_resolver_reads_the_rule_shapes_of_the_snapshot() -> None:
    rules = SNAPSHOT['rosdep']
    assert resolve(rules['python3-numpy']['ubuntu'], 'noble') == ('apt', ['python3-numpy'])
    assert resolve(rules['python3-rosbags-pip']['debian'], 'bookworm') == ('pip', ['rosbags'])
    assert resolve(rules['python3-tqdm']['ubuntu'], 'noble') == ('apt', ['python3-tqdm'])
    assert resolve({'jammy': ['a'], 'noble': None}, 'noble') is None
    assert resolve({'pip': ['duckdb']}, 'noble') == ('pip', ['duckdb'])
    assert resolve(None, 'noble') is None


def test_every_package_xml_key_resolves_on_ubuntu_and_debian_or_is_a_jazzy_package() -> None:
    keys = package_keys()
    recorded = set(SNAPSHOT['rosdep']) | set(SNAPSHOT['jazzy_packages'])
    assert set(keys) <= recorded, f're-record test/data/rosdistro_keys.yaml: ' \
        f'{set(keys) - recorded}'
    assert SNAPSHOT['platforms'] == {'ubuntu': 'noble', 'debian': 'bookworm'}
    assert len(SNAPSHOT['commit']) == 40
    unresolved = {key: os for key in keys if key not in SNAPSHOT['jazzy_packages']
                  for os, codename in SNAPSHOT['platforms'].items()
                  if resolve((SNAPSHOT['rosdep'][key] or {}).get(os), codename) is None}
    assert unresolved == {}
    ros = {key for key in keys if key in SNAPSHOT['jazzy_packages']}
    assert {'rclpy', 'sensor_msgs', 'nav_msgs', 'launch_ros'} <= ros


def test_keys_the_snapshot_lacks_are_not_in_package_xml() -> None:
    """The keys recorded as missing (package.xml's before the fix, and the names one would
    guess for the pip step's packages) stay out of it."""
    missing = {key for key, rule in SNAPSHOT['rosdep'].items() if rule is None}
    assert {'python3-mcap-pip', 'python3-zstandard', 'python3-threadpoolctl',
            'python3-dask-pip'} <= missing
    assert not missing & set(package_keys())
