"""Record what a ros/rosdistro snapshot says about package.xml's dependency keys.

    python test/data/record_rosdistro.py ROSDISTRO_GIT_DIR [EXTRA_KEY ...] \
        > test/data/rosdistro_keys.yaml

ROSDISTRO_GIT_DIR is a clone (bare or not) of https://github.com/ros/rosdistro. For every
``<*depend>`` key of package.xml, and every EXTRA_KEY (keys checked and found missing, kept as a
record), it writes the Ubuntu and Debian rules of rosdep/base.yaml or rosdep/python.yaml (null:
neither file has the key), and which of the keys are packages released in Jazzy
(jazzy/distribution.yaml). test_rosdep_keys.py resolves them for Jazzy's platforms offline.
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys
from typing import Any
import xml.etree.ElementTree as ET

import yaml

REPO = Path(__file__).resolve().parents[2]
ROSDEP_FILES = ('rosdep/base.yaml', 'rosdep/python.yaml')
DISTRO = 'jazzy'


def package_keys() -> list[str]:
    """Every ``<*depend>`` key of package.xml, in file order, once."""
    root = ET.parse(REPO / 'package.xml').getroot()
    return list(dict.fromkeys(e.text for e in root if e.tag.endswith('depend') and e.text))


def show(git_dir: str, commit: str, path: str) -> Any:
    """The YAML file ``path`` of the snapshot."""
    text = subprocess.run(['git', '--git-dir', git_dir, 'show', f'{commit}:{path}'],
                          capture_output=True, text=True, check=True).stdout
    return yaml.safe_load(text)


def record(git_dir: str, extra_keys: list[str]) -> dict[str, Any]:
    """The snapshot's commit, Jazzy's platforms, the rules of the keys and the Jazzy packages
    among them."""
    def git(*args: str) -> str:
        return subprocess.run(['git', '--git-dir', git_dir, *args], capture_output=True,
                              text=True, check=True).stdout.strip()

    commit = git('rev-parse', 'HEAD')
    rules: dict[str, Any] = {}
    for path in ROSDEP_FILES:
        rules.update(show(git_dir, commit, path))
    distribution = show(git_dir, commit, f'{DISTRO}/distribution.yaml')
    released = {package for name, repo in distribution['repositories'].items()
                if 'release' in repo for package in repo['release'].get('packages', [name])}
    keys = list(dict.fromkeys([*package_keys(), *extra_keys]))
    return {
        'source': 'https://github.com/ros/rosdistro',
        'commit': commit,
        'date': git('log', '-1', '--format=%cI', commit),
        'platforms': {os: names[0] for os, names in
                      distribution['release_platforms'].items() if os in ('ubuntu', 'debian')},
        'rosdep': {key: None if key not in rules else
                   {os: rules[key].get(os) for os in ('ubuntu', 'debian')}
                   for key in keys if key not in released},
        f'{DISTRO}_packages': sorted(key for key in keys if key in released),
    }


if __name__ == '__main__':
    print(f'# written by test/data/record_rosdistro.py; see its docstring\n'
          f'{yaml.safe_dump(record(sys.argv[1], sys.argv[2:]), sort_keys=False)}', end='')
