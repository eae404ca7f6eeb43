"""The node's ROS parameters, generated from the typed config tree (:mod:`roadbev_core.config`).

:func:`declare_parameters` declares every parameter of :func:`parameter_specs` with its
description, range and read-only flag (``ros2 param describe``) plus the backend options given at
start; :func:`config_of` builds the validated :class:`RoadbevConfig` from the declared values
(checked against the components too: :func:`roadbev_core.pipeline.check_config`);
:func:`check_overrides` refuses ``-p`` / ``--params-file`` names the node does not know, as
:meth:`RoadbevConfig.from_params` refuses them everywhere else.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from roadbev_core.backend_plugins import option_backend
from roadbev_core.config import ParamError, ParamSpec, RoadbevConfig, load_params_file, parameter_specs
from roadbev_core.config.tree import check_name, is_backend_option
from roadbev_core.pipeline import check_config

# Parameters every rclpy node has (not the config's).
ROS_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})

__all__ = [
    "check_overrides", "check_params_files", "config_of", "declare_parameters", "declare_typed", "descriptor",
    "param_changes", "plain", "report_bad_values", "type_mismatch", "value_error",
]


_TYPE_NAMES = ((bool, "bool"), (int, "integer"), (float, "double"), (str, "string"))  # bool before int


def _type_name(value: Any) -> str | None:
    return next((name for cls, name in _TYPE_NAMES if isinstance(value, cls)), None)


def _kind(value: Any) -> str:
    """How a parameter value reads in a message: ``a double``, ``a list of doubles``..."""
    if isinstance(value, (list, tuple)):
        return "a list" + (f" of {_type_name(value[0]) or type(value[0]).__name__}s" if value else "")
    name = _type_name(value)
    if name is None:
        return type(value).__name__
    return ("an " if name[0] in "aeiou" else "a ") + name + (" (true or false)" if name == "bool" else "")


def type_mismatch(name: str, given: Any, default: Any) -> str:
    """One line saying that ``name`` was given ``given`` where a value of ``default``'s type belongs."""
    hint = ""
    if isinstance(default, float) and isinstance(given, int) and not isinstance(given, bool):
        hint = f" (write {given}.0)"
    elif isinstance(default, list) and default and isinstance(default[0], float):
        hint = " (write every number with a decimal point, e.g. [1.6, 0.0, 1.1])"
    return f"parameter {name}: {given!r} is {_kind(given)}, expected {_kind(default)}{hint}"


def declare_typed(node: Node, name: str, default: Any, descriptor: ParameterDescriptor | None = None) -> Any:
    """Declare ``name`` with ``default`` and return its value.

    Raises:
        ParamError: the start-up value (``-p``, a params file) is of another type than ``default``
            (rclpy's InvalidParameterTypeException, told in one line).
    """
    try:
        return node.declare_parameter(name, default, descriptor or ParameterDescriptor()).value
    except InvalidParameterTypeException:
        given = node._parameter_overrides[name].value  # what -p / --params-file gave
        raise ParamError(type_mismatch(name, given, default)) from None


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS descriptor of one parameter (description, range, choices, read-only)."""
    d = ParameterDescriptor(name=spec.name, description=spec.description, read_only=spec.read_only)
    if spec.choices:
        d.additional_constraints = "one of: " + ", ".join(spec.choices)
    if isinstance(spec.default, (float, list)):
        d.dynamic_typing = True  # accept 1 for 1.0 and [0, 0, 5]; the config coerces
        if isinstance(spec.default, float) and spec.low is not None and spec.high is not None:
            d.floating_point_range = [
                FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high), step=0.0)
            ]
    elif isinstance(spec.default, int) and not isinstance(spec.default, bool) and spec.low is not None \
            and spec.high is not None:
        d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)]
    return d


def plain(value: Any) -> Any:
    """A parameter value as plain Python (rclpy hands arrays as array.array / lists)."""
    if isinstance(value, (list, tuple)) or type(value).__name__ == "array":
        return list(value)
    return value


def check_overrides(names: Iterable[str]) -> None:
    """Refuse start-up overrides (``-p``, ``--params-file``) of parameters the node does not have.

    Raises:
        ParamError: naming the first unknown one.
    """
    for name in names:
        if name not in ROS_PARAMETERS:
            check_name(name)


def value_error(name: str, value: Any) -> str | None:
    """Why a value of one of the config's parameters is refused on its own (type, range,
    choices), or None (a good value, a backend option or a parameter that is not the config's)."""
    spec = next((s for s in parameter_specs() if s.name == name), None)
    if spec is None:
        return None
    try:
        spec.check(value)
    except ParamError as exc:
        return str(exc)
    return None


def report_bad_values(parameters: list[Any], report: Callable[[str, str], None]) -> list[Any]:
    """For rclpy's pre-set-parameters callback: ``report("parameter", ...)`` every value refused
    on its own. It runs before rclpy's own range checks, so a value rclpy refuses is reported too.

    Returns:
        ``parameters``, unchanged.
    """
    for p in parameters:
        error = value_error(p.name, plain(p.value))
        if error:
            report("parameter", f"rejected: {error}")
    return parameters


def param_changes(parameters: Iterable[Any]) -> tuple[str | None, dict[str, Any]]:
    """What a set of ``rclpy.parameter.Parameter`` asks of the config.

    Returns:
        Why the first value refused on its own is refused (:func:`value_error`; None when none
        is), and the config's changes as plain values by name (the parameters every rclpy node
        has, such as ``use_sim_time``, left to rclpy).
    """
    parameters = list(parameters)
    error = next(filter(None, (value_error(p.name, plain(p.value)) for p in parameters)), None)
    return error, {p.name: plain(p.value) for p in parameters if p.name not in ROS_PARAMETERS}


def check_params_files(argv: Sequence[str], node_name: str) -> list[str]:
    """Read every ``--params-file`` of ``argv`` as the node will: a file that applies nothing to
    this node is an error; sections for other nodes are returned as notes (logged, not silent).

    Raises:
        ParamError: a file that cannot be read or has no section for this node.
    """
    notes = []
    for i, arg in enumerate(argv):
        if arg == "--params-file" and i + 1 < len(argv):
            note = load_params_file(argv[i + 1], node_name).note()
            if note:
                notes.append(f"{argv[i + 1]}: {note}")
    return notes


def declare_parameters(node: Node) -> None:
    """Declare every parameter, and the backend options (``<backend>.<option>``) given at start.

    Raises:
        ParamError: a start-up value of the wrong type.
    """
    for spec in parameter_specs():
        try:
            declare_typed(node, spec.name, spec.default, descriptor(spec))
        except InvalidParameterValueException as exc:
            raise ParamError(f"parameter {spec.name}: {exc}") from None
    overrides: Mapping[str, Parameter] = node._parameter_overrides  # what -p / --params-file gave
    check_overrides(overrides)
    for name, override in overrides.items():
        if is_backend_option(name) and not node.has_parameter(name):
            d = ParameterDescriptor(name=name, description=f"option of the {option_backend(name)} backend",
                                    dynamic_typing=True)
            node.declare_parameter(name, override.value, d)


def config_of(node: Node, base: RoadbevConfig | None = None) -> RoadbevConfig:
    """The validated config of the node's declared parameters.

    Raises:
        ParamError: see :meth:`RoadbevConfig.from_params` and :func:`check_config`.
    """
    known = {spec.name for spec in parameter_specs()}
    values = {
        name: plain(node.get_parameter(name).value)
        for name in node.get_parameters_by_prefix("")
        if name in known or is_backend_option(name)
    }
    return check_config(RoadbevConfig.from_params(values, base=base))
