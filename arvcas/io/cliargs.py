"""Command-line argument checks shared by the three command modules (:mod:`arvcas.cli`,
:mod:`arvcas.tuning.cli`, :mod:`arvcas.experiments.cli`): argparse types that refuse a bad count, seed
or duration at parse time, before any work, a memory estimate's refusal, the refusal of options that
do not apply, the ``--format`` option of a command that writes figures, the ``--system`` and
``--n-quad`` options of a command that runs the model, and the files a command declares it will write
(:func:`out_file`, each with the kind it will be written as).

It lives in the I/O layer, below tuning and the experiments, so that every command module imports it
and none imports another's module for it (docs/architecture.md: no import circles); it imports nothing
of arvcas at its top (the command line's start stays light), only :mod:`arvcas.io.style` inside
:func:`figure_file` and :mod:`arvcas.build.calls` (the one memory bound) inside :func:`check_memory`.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

__all__ = ["seed_arg", "count_arg", "seconds_arg", "check_memory", "MAX_SEED", "refuse", "FIGURE_FORMATS",
           "add_figure_format", "figure_file", "model_options", "add_system_arg", "default_system_text", "add_model_args", "output_kinds",
           "out_file", "RESULT_FORMATS"]

MAX_SEED = 2**63  # seeds are stored as int64 and fed to numpy's SeedSequence


def seed_arg(text: str) -> int:
    """A seed: an integer with 0 <= seed < 2**63."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= v < MAX_SEED:
        raise argparse.ArgumentTypeError(f"{text} is out of range (allowed: 0 <= seed < 2**63)")
    return v


def count_arg(lo: int, hi: int, what: str = "count"):
    """An argparse type: an integer ``lo <= n <= hi``."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{v} is out of range (allowed: {lo}..{hi})")
        return v

    parse.__name__ = what
    return parse


def seconds_arg(text: str) -> float:
    """A duration in seconds: finite and positive (not nan, inf, 0 or negative)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"{text}: must be a finite number of seconds > 0")
    return v


def _total_memory() -> int | None:
    from arvcas.build.calls import total_memory

    return total_memory()


def check_memory(what: str, n_bytes: float, share: float = 0.5) -> None:
    """Refuse a request whose results would take more than ``share`` of this machine's memory
    (:func:`arvcas.build.calls.check_memory`, the one memory bound)."""
    from arvcas.build.calls import check_memory as check

    check(what, n_bytes, share, ValueError, _total_memory())


def refuse(a: argparse.Namespace, names, why: str) -> None:
    """ValueError if any of the options ``names`` (dest names) was given (is not None/False)."""
    for n in names:
        v = getattr(a, n, None)
        if v is not None and v is not False:
            raise ValueError(f"--{n.replace('_', '-')}: {why}")


# The formats arvcas writes figures in: :data:`arvcas.io.style.FORMATS` (tests/test_plots.py checks that
# they agree), repeated here so that building the parser does not import the plotting modules.
FIGURE_FORMATS = ("png", "pdf", "svg")


def add_figure_format(p: argparse.ArgumentParser, what: str = "the figures") -> None:
    """``--format png|pdf|svg`` of a command that writes figures (dest ``format``, default None)."""
    p.add_argument("--format", choices=FIGURE_FORMATS, default=None,
                   help=f"format of {what}: png, pdf or svg (default: the file name's suffix, else png)")


def figure_file(path, fmt: str | None, what: str) -> str:
    """The format a figure file ``path`` is written in (``fmt`` or its suffix); ValueError (one line)
    for a format arvcas does not write or a suffix that contradicts ``--format``."""
    from arvcas.io.style import figure_format

    return figure_format(path, fmt, what)


def model_options(n_quad: int):
    from arvcas.model.uvms import ModelOptions

    return ModelOptions(n_quad=n_quad)


def default_system_text() -> str:
    """How a help text names the default system: "the default system, <name>" (:data:`arvcas.system.DEFAULT`)."""
    from arvcas.system import DEFAULT

    return f"the default system, {DEFAULT}"


def add_system_arg(p: argparse.ArgumentParser, default: str | None = None, type=Path) -> None:
    """``--system NAME|FILE`` (old spelling ``--params``); ``default``: what the help says is used without it
    (default: :func:`default_system_text`)."""
    p.add_argument("--system", "--params", dest="system", metavar="NAME|FILE", type=type, default=None,
                   help=f"the system: a shipped one (arvcas systems) or a system file "
                        f"(default: {default or default_system_text()})")


def add_model_args(p: argparse.ArgumentParser) -> None:
    add_system_arg(p)
    p.add_argument("--n-quad", metavar="N", type=count_arg(1, 20, "--n-quad"), default=5,
                   help="Gauss-Legendre points per link for the drag integral (default: 5)")


def output_kinds(outs, formats: dict[str, str]) -> list:
    """``(label, path)`` outputs with the kind (:mod:`arvcas.util.files`) each will be written as, by suffix:
    ``formats`` maps ``h5`` or ``mat`` to the arvcas format written there (others: by suffix)."""
    from arvcas.io.matfile import mat_kind

    kinds = {"h5": formats.get("h5"), "mat": mat_kind(formats["mat"]) if "mat" in formats else None}
    return [(lab, p, kinds.get(p.suffix.lower().lstrip("."))) for lab, p in outs]


def out_file(dest: str, label: str | None = None, **formats: str):
    def outs(a):
        p = getattr(a, dest)
        return [] if p is None else output_kinds([(label or f"--{dest.replace('_', '-')}", Path(p))], formats)

    return outs


RESULT_FORMATS = {"h5": "arvcas-result", "mat": "arvcas-result"}  # io.results.FORMAT, io.matfile's "arvcas-result"
