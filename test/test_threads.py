"""Every entry point runs BLAS on one thread unless the user chose a number (threads.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from railgsa_ros.threads import BLAS_ENV

#: BLAS threads after limit_blas_threads, called after ('first') or before numpy and scipy load
PROBE = ('import sys\n'
         'from railgsa_ros.threads import limit_blas_threads\n'
         'if sys.argv[1] == "first": import numpy, scipy.linalg\n'
         'limit_blas_threads()\n'
         'import numpy, scipy.linalg\n'
         'from threadpoolctl import threadpool_info\n'
         'print(max(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"))')


def blas_threads(order: str, **env: str) -> int:
    """BLAS threads of a fresh process after limit_blas_threads, called with numpy and scipy
    loaded ('first') or not yet ('later'), with ``env`` added."""
    clean = {k: v for k, v in os.environ.items() if k not in BLAS_ENV}
    out = subprocess.run([sys.executable, '-c', PROBE, order], env={**clean, **env},
                         check=True, capture_output=True, text=True).stdout
    return int(out.strip())


def test_one_blas_thread_by_default_and_the_users_choice_kept() -> None:
    for order in ('first', 'later'):
        assert blas_threads(order) == 1, order
        if (os.cpu_count() or 1) > 1:
            assert blas_threads(order, OPENBLAS_NUM_THREADS='2') == 2, order


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


def test_without_threadpoolctl_only_the_variable_is_set(monkeypatch: pytest.MonkeyPatch) -> None:
    from railgsa_ros.threads import limit_blas_threads

    for name in BLAS_ENV:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setitem(sys.modules, 'threadpoolctl', None)  # import raises ImportError
    assert 'numpy' in sys.modules
    limit_blas_threads()
    assert os.environ['OPENBLAS_NUM_THREADS'] == '1'
