"""The text of every generated file that is not CasADi's: Jinja2 templates under ``build/templates/``.

A template is the file a reader sees in the output, with ``{{ value }}`` where a number or a name of
the export goes and ``{% for %}``/``{% if %}`` where the system decides how many lines there are; the
Python of an export computes the values only. The environment is the same for every template:

* ``StrictUndefined``: a value the template names and the caller did not give raises
  :class:`jinja2.UndefinedError` (nothing renders as an empty string by accident);
* no autoescape (the targets are C, Python, Markdown, CMake and Makefiles, each escaped by the
  filters below where it takes user text);
* ``keep_trailing_newline``, ``trim_blocks`` and ``lstrip_blocks``: a line holding only a block tag
  leaves nothing in the output, so the output's lines are the template's lines.

Filters: ``c_comment``, ``c_string``, ``markdown``, ``xml_attr`` (:mod:`arvcas.build.text`),
``c_double`` (the shortest literal that reads back as the same double), ``c_doubles`` (a comma-separated
list of them), ``ident`` (a name as the upper-case tail of a C macro), ``repr`` (Python's),
``fmt`` (Python's ``format(value, spec)``).
"""

from __future__ import annotations

import math
from functools import lru_cache
from importlib import resources

import jinja2

from arvcas.build.text import c_comment, c_string, markdown, xml_attr

__all__ = ["render", "c_double", "ident", "TemplateError"]


class TemplateError(ValueError):
    """A value cannot be written into a generated file (one line)."""


def c_double(v) -> str:
    """The shortest C literal of the double ``v`` that reads back as the same double (``1.0``, ``0.1``,
    ``1e-05``). A value that is not finite raises :class:`TemplateError`."""
    v = float(v)
    if not math.isfinite(v):
        raise TemplateError(f"export-c: cannot write the non-finite value {v} as a C literal")
    r = repr(v)
    return r if ("." in r or "e" in r) else r + ".0"


def c_doubles(values) -> str:
    """``a, b, c``: :func:`c_double` of each value, in order (any nesting is flattened)."""
    import numpy as np

    return ", ".join(c_double(x) for x in np.asarray(values, dtype=float).ravel())


def ident(name: str) -> str:
    """``name`` as the tail of a C macro: every character that is not an ASCII letter or digit becomes ``_``,
    letters upper case."""
    return "".join(c if c.isascii() and c.isalnum() else "_" for c in name).upper()


@lru_cache(maxsize=1)
def _environment() -> jinja2.Environment:
    root = resources.files("arvcas") / "build" / "templates"
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(root)), undefined=jinja2.StrictUndefined,
                             autoescape=False, keep_trailing_newline=True, trim_blocks=True, lstrip_blocks=True)
    env.filters.update(c_comment=c_comment, c_string=c_string, markdown=markdown, xml_attr=xml_attr,
                       c_double=c_double, c_doubles=c_doubles, ident=ident, repr=repr, fmt=format)
    return env


def render(template: str, values: dict, error: type[Exception] = TemplateError) -> str:
    """The text of ``templates/<template>`` with ``values``; a name the template uses that is not among
    them raises :class:`jinja2.UndefinedError`, a value a filter cannot write ``error`` (one line)."""
    try:
        return _environment().get_template(template).render(**values)
    except TemplateError as e:
        raise error(str(e)) from None
