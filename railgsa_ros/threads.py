"""One BLAS thread per process, unless the user chose a number.

The core's linear algebra is small (7 x 7 banks, Cholesky factors of a few thousand), so BLAS
threads gain nothing, and OpenBLAS's idle threads spin: on a 2-core machine shared with other
work, ``railgsa calibrate`` took 14.8 s with OpenBLAS's default threads and 2.2 s with one
(measured, load average 4). In-train computers share their few cores with other monitoring, so
every entry point (the CLI and each node) limits BLAS to one thread. A user who sets
OPENBLAS_NUM_THREADS, OMP_NUM_THREADS or MKL_NUM_THREADS keeps their choice. threadpoolctl
limits only libraries already loaded, so numpy and scipy.linalg (each has its own OpenBLAS) are
imported first: the core imports both anyway.
"""

from __future__ import annotations

import os

#: environment variables by which a user chooses the BLAS thread count
BLAS_ENV = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')


def limit_blas_threads() -> None:
    """Limit this process's BLAS libraries to one thread unless BLAS_ENV names a choice."""
    if any(os.environ.get(name) for name in BLAS_ENV):
        return
    import numpy  # noqa: F401  (loads numpy's BLAS)
    import scipy.linalg  # noqa: F401  (loads scipy's)
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api='blas')
