"""What setup.py gives setuptools, read without building anything (shared by the packaging and
launch-file tests)."""

from __future__ import annotations

from pathlib import Path
import runpy
from typing import Any

import pytest
import setuptools

REPO = Path(__file__).resolve().parents[1]


def setup_kwargs(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """The keyword arguments setup.py passes to setuptools.setup (nothing is built)."""
    captured: dict[str, Any] = {}
    monkeypatch.setattr(setuptools, 'setup', lambda **kw: captured.update(kw))
    monkeypatch.chdir(REPO)
    runpy.run_path(str(REPO / 'setup.py'), run_name='__main__')
    return captured
