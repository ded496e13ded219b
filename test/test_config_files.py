"""Configuration files that are not configuration files: devices, pipes, huge files and files
full of secrets (``--vehicle``, ``--params``; ``config.load_yaml`` reads them all).

Each command runs in a subprocess capped at 1 GiB of address space and 60 s, so the old
behaviour (reading /dev/zero until memory runs out, blocking on a pipe) fails the test instead
of the machine.
"""

from __future__ import annotations

import os
from pathlib import Path
import resource
import subprocess
import sys

import pytest

from railgsa_ros.cli.main import main
from railgsa_ros.config import MAX_BYTES, key_list, load_yaml
from railgsa_ros.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
# /etc/shadow-like lines (never the machine's own file): each one is a YAML mapping key
SHADOW = ('root:$y$j9T$s3cretSalt$hashhashhash:19700:0:99999:7:::\n'
          'daemon:*:19700:0:99999:7:::\n'
          'alice:$6$pepper$0123456789abcdef:19700:0:99999:7:::\n')


def _cap() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))


def _railgsa(*argv: str) -> subprocess.CompletedProcess:
    env = {**os.environ, 'PYTHONPATH': str(ROOT)}
    return subprocess.run([sys.executable, '-m', 'railgsa_ros.cli.main', *argv], env=env,
                          capture_output=True, text=True, timeout=60, preexec_fn=_cap)


def _vehicle(path: str) -> list[str]:
    return ['bode', '--vehicle', path, '--out', os.devnull + '.png']


def _params(path: str) -> list[str]:  # the options are read before the bag
    return ['fleet', 'ingest', 'no-such-bag', '--db', 'unused.duckdb', '--params', path]


@pytest.mark.parametrize('command', [_vehicle, _params], ids=['vehicle', 'params'])
def test_devices_and_pipes_are_refused_in_one_line(command, tmp_path):
    """/dev/zero grew to 6-8 GB and hung; a named pipe without a writer blocked for ever. Now:
    exit 2, one line naming the file and what is wrong."""
    fifo = tmp_path / 'pipe.yaml'
    os.mkfifo(fifo)
    for path in ('/dev/zero', str(fifo)):
        proc = _railgsa(*command(path))
        assert proc.returncode == 2, (path, proc.stderr[-500:])
        assert proc.stderr == f'error: {path}: not a regular file (a device, pipe or ' \
                              'directory)\n'


@pytest.mark.parametrize('command', [_vehicle, _params], ids=['vehicle', 'params'])
def test_errors_never_echo_the_file(command, tmp_path, capsys):
    """A file of password hashes given by mistake: one line naming the file and what it lacks,
    no line, key or hash of it (``--params`` listed its lines as the 'sections' it found)."""
    secrets = tmp_path / 'shadow'
    secrets.write_text(SHADOW)
    capsys.readouterr()
    assert main(command(str(secrets))) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'error: {secrets}: ') and err.count('\n') == 1, err
    said = err[len(f'error: {secrets}: '):]
    for word in ('root', 'daemon', 'alice', 's3cret', 'pepper', 'hash', '19700', '$'):
        assert word not in said, said


def test_names_are_still_named():
    """A mistyped parameter or field is still named (the messages say which key is wrong);
    only what does not look like a name is counted instead of quoted."""
    assert key_list(['rate_hz', 'gain', 3, None]) == '3, None, gain, rate_hz'
    assert key_list(['m_s', 'x' * 65, 'a b', 'p@ss', 10**400]) == \
        'm_s, 4 more keys that are not a name'


def test_a_file_up_to_1_mib_is_read_and_larger_ones_or_directories_refused(tmp_path):
    path = tmp_path / 'big.yaml'
    path.write_text('# ' + 'x' * (MAX_BYTES - 40) + '\nvehicle: {m_s: 40000.0}\n')
    assert load_yaml(path) == {'vehicle': {'m_s': 40000.0}}
    path.write_text('# ' + 'x' * MAX_BYTES + '\n')
    with pytest.raises(ConfigError, match=f'^{path}: larger than 1 MiB: not a configuration'):
        load_yaml(path)
    with pytest.raises(ConfigError, match=f'^{tmp_path}: not a regular file'):
        load_yaml(tmp_path)
