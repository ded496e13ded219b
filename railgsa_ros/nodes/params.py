"""Declarative ROS parameters: one ParamSpec per parameter gives its descriptor and checks.

rclpy itself enforces the type, the numeric range and read_only; ``choices`` (string enums) are
checked here. ``declare`` turns any rejection at start-up into a ConfigError naming the parameter.
An integer given for a float parameter (``-p speed_mps:=30``) is taken as that float, and one
given for a string parameter (an id: ``-p track:=2``) as its text, at start-up (``declare``) and
later (``accept_integers``, a pre-set callback); other wrong types are refused.
``check_params_files`` reads every ``--params-file`` of the command line before rclpy does: a
missing or malformed file, an unknown key or no section for the node is a ConfigError naming the
file (rcl alone ignores unknown keys and other nodes' sections).
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from railgsa_ros.config import load_yaml, ros_parameters
from railgsa_ros.errors import ConfigError


@dataclass(frozen=True)
class ParamSpec:
    """A parameter: name, default (its type is the parameter's type), description with units,
    optional inclusive numeric bounds, string choices, and read_only (fixed after start-up)."""

    name: str
    default: bool | int | float | str
    description: str
    bounds: tuple[float, float] | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False

    def descriptor(self) -> ParameterDescriptor:
        """The ParameterDescriptor advertised to `ros2 param describe`."""
        desc = ParameterDescriptor(name=self.name, description=self.description,
                                   read_only=self.read_only)
        if self.choices:
            desc.additional_constraints = 'one of: ' + ', '.join(self.choices)
        if self.bounds is not None:
            low, high = self.bounds
            if isinstance(self.default, float):
                desc.floating_point_range = [FloatingPointRange(
                    from_value=float(low), to_value=float(high), step=0.0)]
            else:
                desc.integer_range = [IntegerRange(from_value=int(low), to_value=int(high),
                                                   step=1)]
        return desc

    def check(self, value: Any) -> str | None:
        """Reason why ``value`` is not acceptable beyond rclpy's own checks, or None."""
        if self.choices and value not in self.choices:
            return f'{self.name}: {value!r} is not one of {", ".join(self.choices)}'
        return None


def as_float(param: Parameter, specs: Mapping[str, ParamSpec]) -> Parameter:
    """``param`` as a DOUBLE when it is an INTEGER for a float spec, as a STRING when it is an
    INTEGER for a string spec (an id such as ``track: 2``, as the offline params files read it),
    else unchanged."""
    spec = specs.get(param.name)
    if spec is None or param.type_ != Parameter.Type.INTEGER:
        return param
    if isinstance(spec.default, float):
        return Parameter(param.name, Parameter.Type.DOUBLE, float(param.value))
    if isinstance(spec.default, str):
        return Parameter(param.name, Parameter.Type.STRING, str(param.value))
    return param


def accept_integers(specs: Iterable[ParamSpec]) -> Callable[[list[Parameter]], list[Parameter]]:
    """A pre-set-parameters callback turning integers for float ``specs`` into floats."""
    by_name = {s.name: s for s in specs}
    return lambda params: [as_float(p, by_name) for p in params]


def declare(node: Node, specs: Iterable[ParamSpec]) -> dict[str, Any]:
    """Declare every spec on ``node`` (overrides from --ros-args apply); return name -> value.

    Already declared parameters keep their current value (a lifecycle node configured again).
    Raises ConfigError naming the parameter for a wrong type, an out-of-range value or a value
    that is not one of its choices.
    """
    values = {}
    specs = tuple(specs)
    overrides = getattr(node, '_parameter_overrides', {})  # rclpy keeps --ros-args -p here
    by_name = {s.name: s for s in specs}
    for name, override in list(overrides.items()):
        overrides[name] = as_float(override, by_name)
    for spec in specs:
        if node.has_parameter(spec.name):
            values[spec.name] = node.get_parameter(spec.name).value
            continue
        try:
            param = node.declare_parameter(spec.name, spec.default, spec.descriptor())
        except InvalidParameterTypeException:
            raise ConfigError(f'parameter {spec.name}: expected a '
                              f'{type(spec.default).__name__}') from None
        except InvalidParameterValueException as exc:
            raise ConfigError(f'parameter {spec.name}: {exc}') from None
        reason = spec.check(param.value)
        if reason is not None:
            raise ConfigError(f'parameter {reason}')
        values[spec.name] = param.value
    return values


def merged(current: Mapping[str, Any], specs: Sequence[ParamSpec],
           changes: Iterable[Parameter]) -> tuple[dict[str, Any], str | None]:
    """Current values updated with ``changes`` (only declared specs), and the first reason to
    reject one of them (None if all pass ``ParamSpec.check``)."""
    by_name = {s.name: s for s in specs}
    values, reasons = dict(current), []
    for param in changes:
        spec = by_name.get(param.name)
        if spec is not None:
            reasons.append(spec.check(param.value))
            values[param.name] = param.value
    return values, next((r for r in reasons if r is not None), None)


def ros_arg_values(argv: Sequence[str], flags: Collection[str]) -> list[str]:
    """Values following any of ``flags`` inside ``--ros-args ... [--]`` sections of argv."""
    values, inside = [], False
    args = iter(argv)
    for arg in args:
        if arg == '--ros-args':
            inside = True
        elif arg == '--':
            inside = False
        elif inside and arg in flags:
            values.append(next(args, ''))
    return values


def check_params_files(argv: Sequence[str], node_name: str, known: Collection[str],
                       shared_known: Collection[str]) -> None:
    """ConfigError naming the file for each ``--params-file`` of ``argv`` that is missing or
    malformed, has no section for the node (its name, or ``__node:=`` / ``__name:=`` remapped)
    or sets a parameter outside ``known`` (``/**`` sections: outside ``shared_known``, the
    names of every railgsa node). With ``__ns:=`` the sections are matched as rcl does for that
    namespace (a bare ``<node>:`` section, root-only, does not count)."""
    namespace = None
    for remap in ros_arg_values(argv, ('-r', '--remap')):
        rule, _, value = remap.partition(':=')
        if rule in ('__node', '__name') and value:
            node_name = value
        elif rule == '__ns' and value:
            namespace = '/' + value.strip('/')
    for path in ros_arg_values(argv, ('--params-file',)):
        if not path:
            raise ConfigError('--params-file: no file given')
        ros_parameters(load_yaml(path), node_name, known, path, shared_known=shared_known,
                       namespace=namespace)
