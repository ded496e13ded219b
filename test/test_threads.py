"""Every entry point runs BLAS on one thread unless the user chose a number (threads.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from railgsa_ros.threads import BLAS_ENV

PROBE = ('import numpy, scipy.linalg\nfrom threadpoolctl import threadpool_info\n'
         'from railgsa_ros.threads import limit_blas_threads\n'
         'limit_blas_threads()\n'
         'print(max(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"))')


def blas_threads(**env: str) -> int:
    """BLAS threads of a fresh process after limit_blas_threads, with ``env`` added."""
    clean = {k: v for k, v in os.environ.items() if k not in BLAS_ENV}
    out = subprocess.run([sys.executable, '-c', PROBE], env={**clean, **env}, check=True,
                         capture_output=True, text=True).stdout
    return int(out.strip())


def test_one_blas_thread_by_default_and_the_users_choice_kept() -> None:
    assert blas_threads() == 1
    if (os.cpu_count() or 1) > 1:
        assert blas_threads(OPENBLAS_NUM_THREADS='2') == 2


@pytest.mark.parametrize('entry', ['cli', 'node'])
def test_the_cli_and_the_nodes_limit_blas_threads(entry: str,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    import railgsa_ros.threads as threads

    calls: list[int] = []
    monkeypatch.setattr(threads, 'limit_blas_threads', lambda: calls.append(1))
    if entry == 'cli':
        from railgsa_ros.cli import main as cli

        monkeypatch.setattr(cli, 'limit_blas_threads', threads.limit_blas_threads)
        with pytest.raises(SystemExit):
            cli.main(['--version'])
    else:
        from railgsa_ros.nodes import console_main

        assert console_main(lambda args: 0) == 0
    assert calls == [1]
