"""A truncated or corrupt bag given to `railgsa invert` and `railgsa review`: one line
``error: <bag>: ...``, exit 2, nothing written (`railgsa replay`: test_replay_node.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from test_playback_bags import damaged_bag

from railgsa_ros.cli.main import main

pytest.importorskip('rosbags')

COMMANDS = {
    'invert': lambda bag, out: ['invert', str(bag), '--csv', str(out)],
    'review': lambda bag, out: ['review', str(bag), '--out', str(out), '--no-uncertainty'],
}


@pytest.mark.parametrize('kind', ['truncated-mcap', 'corrupt-sqlite3', 'garbage'])
@pytest.mark.parametrize('command', list(COMMANDS))
def test_damaged_bag_exits_2_naming_it(command: str, kind: str, tmp_path: Path,
                                       capsys: Any) -> None:
    bag, named = damaged_bag(kind, tmp_path)
    out = tmp_path / 'out'
    assert main(COMMANDS[command](bag, out)) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'error: {named}') and err.count('\n') == 1, err
    assert 'Traceback' not in err and not out.exists()
