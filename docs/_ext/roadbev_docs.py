"""Sphinx extension of the RoadBEV documentation: what the code defines is generated from the
code, so a page cannot drift from it.

- ``roadbev-parameters``: the table of the node's parameters, from the parameter descriptors
  (:func:`roadbev_core.config.parameter_specs`: name, type, default, range, read-only,
  description).
- ``roadbev-node-defaults:: module.ATTRIBUTE``: the parameters of a reference node from its
  ``{name: default}`` dict; the directive's content gives one ``name: description`` line per
  parameter, and a parameter without a line (or a line for no parameter) is a build error.
- ``roadbev-modules:: package`` (on reStructuredText pages): an ``automodule`` section for every
  public module of a package (a package's own section documents what its ``__init__`` defines;
  what it re-exports is documented once, in the module that defines it).
- :func:`cli_parser`: the parser the command-line page shows (sphinx-argparse's ``:func:``).

Docstrings are plain text first: ``|x|`` there is an absolute value, not a reStructuredText
substitution, so :func:`escape_bars` escapes every ``|`` outside inline literals and literal
blocks before autodoc renders a docstring; and ``a, b: text`` in an Args or Attributes section
names several fields at once (:func:`join_grouped_fields`). A Python reference on a written page
that names no documented object is a warning (which ``make docs``, ``-W``, makes an error).

The table rows are plain functions (:func:`parameter_rows`, :func:`default_rows`), which
``tests/package/test_docs.py`` checks without running Sphinx.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from docutils import nodes
from sphinx.addnodes import pending_xref
from sphinx.application import Sphinx
from sphinx.environment import BuildEnvironment
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective

LOGGER = logging.getLogger(__name__)

PARAMETER_HEADER = ("Parameter", "Type", "Default", "Range", "Run-time change", "Description")
DEFAULTS_HEADER = ("Parameter", "Type", "Default", "Description")


def ros_type(default: Any) -> str:
    """The ROS parameter type of a default value (bool, integer, double, string, double[N])."""
    if isinstance(default, bool):
        return "bool"
    if isinstance(default, int):
        return "integer"
    if isinstance(default, float):
        return "double"
    if isinstance(default, str):
        return "string"
    if isinstance(default, (list, tuple)):
        return f"double[{len(default)}]"
    return type(default).__name__


def format_value(value: Any) -> str:
    """A value as a params YAML writes it (``true``, ``0.03``, ``[0.8, -0.8]``, ``""``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"' if value == "" else value
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    return repr(value) if isinstance(value, float) else str(value)


def value_range(low: float | None, high: float | None, choices: Sequence[str] | None) -> str:
    """The allowed values: ``[low, high]`` (a missing bound is open), or the choices."""
    if choices:
        return "one of " + ", ".join(choices)
    if low is None and high is None:
        return ""
    lo = "-inf" if low is None else format_value(low)
    hi = "inf" if high is None else format_value(high)
    return f"[{lo}, {hi}]"


def parameter_rows(specs: Iterable[Any]) -> list[tuple[str, ...]]:
    """One row per parameter descriptor (:class:`roadbev_core.config.ParamSpec`), in their order,
    with the columns of :data:`PARAMETER_HEADER`."""
    return [
        (spec.name, ros_type(spec.default), format_value(spec.default),
         value_range(spec.low, spec.high, spec.choices), "no (read-only)" if spec.read_only else "yes",
         spec.description)
        for spec in specs
    ]


def default_rows(defaults: Mapping[str, Any], descriptions: Mapping[str, str]) -> list[tuple[str, ...]]:
    """One row per entry of a node's ``{name: default}``, with the columns of
    :data:`DEFAULTS_HEADER`.

    Raises:
        ValueError: a parameter without a description, or a description of no parameter.
    """
    missing = [name for name in defaults if name not in descriptions]
    unknown = [name for name in descriptions if name not in defaults]
    if missing or unknown:
        problems = ([f"no description of {', '.join(missing)}"] if missing else []) + (
            [f"descriptions of unknown parameters {', '.join(unknown)}"] if unknown else [])
        raise ValueError("; ".join(problems))
    return [(name, ros_type(value), format_value(value), descriptions[name]) for name, value in defaults.items()]


def _unimportable(name: str) -> None:
    # pkgutil would skip a package that fails to import, and its modules would vanish from the API
    raise ImportError(f"{name} cannot be imported for the API pages")


def public_modules(package: str) -> list[str]:
    """``package`` and every module under it, sorted, without private (``_x``) and ``__main__``
    modules.

    Raises:
        ImportError: a package under it cannot be imported.
    """
    root = importlib.import_module(package)
    names = [package]
    for info in pkgutil.walk_packages(root.__path__, prefix=f"{package}.", onerror=_unimportable):
        if any(part.startswith("_") for part in info.name.split(".")):
            continue
        names.append(info.name)
    return sorted(names)


_INLINE_LITERAL = re.compile(r"``.+?``", re.DOTALL)


def _escape_text(text: str) -> str:
    """``text`` with every ``|`` outside inline literals escaped."""
    out, pos = [], 0
    for match in _INLINE_LITERAL.finditer(text):
        out += [text[pos:match.start()].replace("|", "\\|"), match.group()]
        pos = match.end()
    out.append(text[pos:].replace("|", "\\|"))
    return "".join(out)


def escape_bars(lines: Sequence[str]) -> list[str]:
    """Docstring lines with every ``|`` escaped except in inline literals (which may span lines)
    and literal blocks (the indented lines after a paragraph ending in ``::``)."""
    out: list[str] = []
    prose: list[str] = []
    literal_indent: int | None = None  # inside a literal block: the indent of the line that opened it
    opener: int | None = None  # after a line ending in "::": its indent
    for line in lines:
        indent = len(line) - len(line.lstrip())
        if literal_indent is not None and line.strip() and indent <= literal_indent:
            literal_indent = None
        if literal_indent is not None:
            out.append(line)
            continue
        if opener is not None and line.strip():
            # the first line after the "::" line: a literal block when indented further
            base, opener = opener, None
            if indent > base:
                out += _escape_text("\n".join(prose)).split("\n")
                prose = []
                literal_indent = base
                out.append(line)
                continue
        prose.append(line)
        if line.rstrip().endswith("::"):
            opener = indent
    if prose:
        out += _escape_text("\n".join(prose)).split("\n")
    return out


# a field napoleon made of "a, b, c: text" in an Args or Attributes section
_GROUPED_FIELD = re.compile(r"^(\s*:(?:param|ivar) )(\w+(?:, \w+)+):")


def join_grouped_fields(lines: Sequence[str]) -> list[str]:
    """``:ivar a, b, c:`` (several names, one description) as ``:ivar a,b,c:``: with the spaces,
    Sphinx would read ``a, b,`` as the type of ``c`` and link the names as types."""
    return [_GROUPED_FIELD.sub(lambda m: m.group(1) + m.group(2).replace(", ", ",") + ":", line) for line in lines]


def _plain_docstring(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    lines[:] = join_grouped_fields(escape_bars(lines))


def _escape_parser(parser: argparse.ArgumentParser) -> None:
    """Escape ``|`` in every help text, description and epilog of ``parser`` and its
    sub-commands: sphinx-argparse reads them as reStructuredText."""
    for attr in ("description", "epilog"):
        if getattr(parser, attr):
            setattr(parser, attr, getattr(parser, attr).replace("|", "\\|"))
    for action in parser._actions:
        if action.help:
            action.help = action.help.replace("|", "\\|")
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                if choice.help:
                    choice.help = choice.help.replace("|", "\\|")
            for sub in action.choices.values():
                _escape_parser(sub)


def cli_parser() -> argparse.ArgumentParser:
    """``roadbev``'s full parser (:func:`roadbev_cli.cli.full_parser`) as the command-line page
    shows it: the help texts are plain text, so their ``|`` are escaped."""
    from roadbev_cli.cli import full_parser

    parser = full_parser()
    _escape_parser(parser)
    return parser


def _table(header: Sequence[str], rows: Sequence[Sequence[str]], widths: Sequence[int],
           literal_columns: int) -> nodes.table:
    """A docutils table; the first ``literal_columns`` columns are set as code."""
    group = nodes.tgroup(cols=len(header))
    group += [nodes.colspec(colwidth=w) for w in widths]

    def row(cells: Sequence[str], literal: int) -> nodes.row:
        out = nodes.row()
        for i, text in enumerate(cells):
            entry = nodes.entry()
            para = nodes.paragraph()
            para += nodes.literal(text, text) if i < literal and text else nodes.Text(text)
            entry += para
            out += entry
        return out

    head = nodes.thead()
    head += row(header, 0)
    body = nodes.tbody()
    body += [row(cells, literal_columns) for cells in rows]
    group += head
    group += body
    table = nodes.table(classes=["longtable"])
    table += group
    return table


class ParametersDirective(SphinxDirective):
    """``roadbev-parameters``: the node's parameter table."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        from roadbev_core.config import parameter_specs

        return [_table(PARAMETER_HEADER, parameter_rows(parameter_specs()), (22, 8, 14, 14, 8, 34), 3)]


class NodeDefaultsDirective(SphinxDirective):
    """``roadbev-node-defaults:: module.ATTRIBUTE`` with ``name: description`` lines."""

    required_arguments = 1
    has_content = True

    def run(self) -> list[nodes.Node]:
        module_name, _, attribute = self.arguments[0].rpartition(".")
        defaults = getattr(importlib.import_module(module_name), attribute)
        descriptions: dict[str, str] = {}
        for line in self.content:
            if line.strip():
                name, sep, text = line.partition(":")
                if not sep:
                    raise self.error(f"not a 'name: description' line: {line!r}")
                descriptions[name.strip()] = text.strip()
        try:
            rows = default_rows(defaults, descriptions)
        except ValueError as exc:
            raise self.error(f"{self.arguments[0]}: {exc}") from None
        return [_table(DEFAULTS_HEADER, rows, (24, 8, 18, 50), 3)]


class ModulesDirective(SphinxDirective):
    """``roadbev-modules:: package``: a section with ``automodule`` for each public module."""

    required_arguments = 1
    has_content = False

    def run(self) -> list[nodes.Node]:
        lines: list[str] = []
        for name in public_modules(self.arguments[0]):
            lines += [f"``{name}``", "-" * (len(name) + 4), "", f".. automodule:: {name}", "   :members:"]
            if hasattr(importlib.import_module(name), "__path__"):  # a package: its own definitions only
                lines.append("   :ignore-module-all:")
            lines.append("")
        return self.parse_text_to_nodes("\n".join(lines), allow_section_headings=True)


def _check_page_reference(app: Sphinx, env: BuildEnvironment, node: pending_xref,
                          contnode: nodes.Element) -> None:
    """Warn of a Python reference on a written page (not an API page) that names nothing: the
    pages' links into the API must not rot silently. (Docstrings' references stay unchecked: they
    also name numpy, torch and rclpy objects these pages do not document.)"""
    if node.get("refdomain") == "py" and not str(node.get("refdoc", "")).startswith("api/"):
        LOGGER.warning("%s names no documented object", node["reftarget"], location=node)


def setup(app: Sphinx) -> dict[str, Any]:
    """Register the directives."""
    app.add_directive("roadbev-parameters", ParametersDirective)
    app.add_directive("roadbev-node-defaults", NodeDefaultsDirective)
    app.add_directive("roadbev-modules", ModulesDirective)
    app.connect("autodoc-process-docstring", _plain_docstring, priority=600)  # after napoleon (500)
    app.connect("missing-reference", _check_page_reference)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
