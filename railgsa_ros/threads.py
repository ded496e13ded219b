"""One BLAS thread per process, unless the user chose a number.

The core's linear algebra is small (7 x 7 banks, Cholesky factors of a few thousand), so BLAS
threads gain nothing, and OpenBLAS's idle threads spin: on a 2-core machine shared with other
work, ``railgsa calibrate`` took 14.8 s with OpenBLAS's default threads and 2.2 s with one
(measured, load average 4). In-train computers share their few cores with other monitoring, so
every entry point (the CLI and each node) limits BLAS to one thread. A user who sets
OPENBLAS_NUM_THREADS, OMP_NUM_THREADS or MKL_NUM_THREADS keeps their choice.

OpenBLAS reads OPENBLAS_NUM_THREADS when it is loaded, so setting it costs nothing and holds for
every library loaded later (numpy and scipy each bring their own OpenBLAS) and for child
processes; libraries loaded already (a caller that imported numpy first) are limited with
threadpoolctl. Importing them here instead would add 0.35 s to every command (measured on
``railgsa --version``), also to those that never load scipy. Without threadpoolctl (a ROS
install whose rosdep did not provide it) those already loaded keep their threads: only the
variable is set.
"""

from __future__ import annotations

import os
import sys

#: environment variables by which a user chooses the BLAS thread count
BLAS_ENV = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')


def limit_blas_threads() -> None:
    """Limit this process's BLAS libraries to one thread unless BLAS_ENV names a choice."""
    if any(os.environ.get(name) for name in BLAS_ENV):
        return
    os.environ['OPENBLAS_NUM_THREADS'] = '1'
    if 'numpy' in sys.modules or 'scipy' in sys.modules:  # loaded before the variable was set
        try:
            from threadpoolctl import threadpool_limits
        except ImportError:
            return
        threadpool_limits(1, user_api='blas')
