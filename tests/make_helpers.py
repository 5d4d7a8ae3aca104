"""``make`` of an exported package (export-c, export-controller) at the tests' optimisation level."""

from __future__ import annotations

from arvcas.build import codegen


def make_cmd(directory, *targets: str) -> list[str]:
    """``make -C directory targets`` with the package's ``ARVCAS_CFLAGS`` at :func:`codegen.default_opt_level`
    (-O0 under tests/conftest.py) in place of its -O2: the same bits (``-ffp-contract=off``), a compile a few
    times shorter. tests/test_export.py checks the Makefile's own flags."""
    cflags = " ".join([codegen.default_opt_level(), *codegen.FIXED_FLAGS])
    return ["make", "-C", str(directory), f"ARVCAS_CFLAGS={cflags}", *targets]
