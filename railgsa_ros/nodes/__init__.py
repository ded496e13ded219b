"""ROS 2 nodes (thin adapters over the core) and the helpers they share."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any


def parameter_overrides(values: Mapping[str, Any]) -> list:
    """rclpy Parameters from plain values (lists become string arrays), for callers without ROS.

    The CLI passes plain values so that only ``railgsa_ros.nodes`` imports rclpy.
    """
    from rclpy.parameter import Parameter

    return [Parameter(k, Parameter.Type.STRING_ARRAY, list(v)) if isinstance(v, (list, tuple))
            else Parameter(k, value=v) for k, v in values.items()]


def console_main(run: Callable[[list[str] | None], int], args: list[str] | None = None) -> int:
    """Console entry point around ``run(args)``: its exit code, or 2 with one line
    ``error: <message>`` on stderr for a RailGsaError (bad input, bad parameters)."""
    import sys

    from railgsa_ros.errors import RailGsaError
    from railgsa_ros.threads import limit_blas_threads

    limit_blas_threads()
    try:
        return run(args)
    except RailGsaError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
