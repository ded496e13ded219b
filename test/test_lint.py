"""The whole repository is ruff clean, and the core passes mypy (both configured in
pyproject.toml)."""

from __future__ import annotations

import hashlib
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile

import pytest

REPO = Path(__file__).resolve().parents[1]


def tool_command(name: str) -> list[str]:
    """The tool next to this Python, else on PATH; skip when it is not installed."""
    local = Path(sys.executable).parent / name
    found = str(local) if local.exists() else shutil.which(name)
    if found is None:
        pytest.skip(f'{name} is not installed (pip install -e ".[dev]")')
    return [found]


def test_ruff_check_is_clean() -> None:
    result = subprocess.run([*tool_command('ruff'), 'check', '--no-cache', '.'], cwd=REPO,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def test_mypy_passes_on_the_core() -> None:
    # incremental cache outside the tree, one per checkout: ~25 s cold, under 1 s warm
    cache = Path(tempfile.gettempdir()) / ('railgsa-mypy-'
                                           + hashlib.sha1(str(REPO).encode()).hexdigest()[:12])
    result = subprocess.run([*tool_command('mypy'), '--cache-dir', str(cache)], cwd=REPO,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
