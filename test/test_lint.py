"""The whole repository is ruff clean (rules in pyproject.toml)."""

from __future__ import annotations

from pathlib import Path
import shutil
import subprocess
import sys

import pytest

REPO = Path(__file__).resolve().parents[1]


def ruff_command() -> list[str]:
    """ruff next to this Python, else on PATH; skip when it is not installed."""
    local = Path(sys.executable).parent / 'ruff'
    found = str(local) if local.exists() else shutil.which('ruff')
    if found is None:
        pytest.skip('ruff is not installed (pip install -e .[test])')
    return [found]


def test_ruff_check_is_clean() -> None:
    result = subprocess.run([*ruff_command(), 'check', '--no-cache', '.'], cwd=REPO,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
