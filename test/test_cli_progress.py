"""The progress bar of ``railgsa invert``: tqdm over the bag's IMU messages on a terminal, none
in a log or pipe, with --quiet or without tqdm; the output is the same either way."""

from __future__ import annotations

import io
from pathlib import Path
import sys

import pytest

from railgsa_ros.bag import read_imu
from railgsa_ros.cli.main import main


class Terminal(io.StringIO):
    """stderr as a terminal."""

    def isatty(self) -> bool:
        return True


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('progress') / 'run'
    assert main(['simulate', '--out', str(path), '--duration', '12', '--speed', '20']) == 0
    return path


def invert(bag: Path, csv: Path, *extra: str) -> str:
    """Run ``railgsa invert`` (stderr as it is), return the CSV."""
    assert main(['invert', str(bag), '--csv', str(csv), *extra]) == 0
    return csv.read_text()


def test_no_bar_off_a_terminal_with_quiet_or_without_tqdm(
        bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    plain = invert(bag, tmp_path / 'plain.csv')  # capsys: not a terminal
    assert '\r' not in capsys.readouterr().err
    for name, extra, block_tqdm in (('quiet', ('--quiet',), False), ('no_tqdm', (), True)):
        with monkeypatch.context() as m:
            m.setattr(sys, 'stderr', Terminal())
            if block_tqdm:
                m.setitem(sys.modules, 'tqdm', None)  # as if not installed
            assert invert(bag, tmp_path / f'{name}.csv', *extra) == plain
            assert '\r' not in sys.stderr.getvalue() and 'msg' not in sys.stderr.getvalue()


def test_bar_on_a_terminal_counts_every_imu_message(bag: Path, tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip('tqdm')
    n = read_imu(bag).stamps_ns.size
    stderr = Terminal()
    monkeypatch.setattr(sys, 'stderr', stderr)
    invert(bag, tmp_path / 'out.csv')
    text = stderr.getvalue()
    assert '\r' in text and 'invert: 100%' in text and f'{n}/{n}' in text
    assert f'{n + 1}/' not in text  # never past the bag's count
