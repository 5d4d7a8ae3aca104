"""A build's progress line: within :func:`report_progress`, every build that takes longer than a threshold
says on a stream what it compiles and, when it ends, how long it took (the command line points it at
standard error). :mod:`arvcas.build.codegen` opens a :class:`Progress` around each build.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from typing import Iterator

__all__ = ["report_progress", "Progress", "PROGRESS_AFTER_S"]

PROGRESS_AFTER_S = 1.0  # a build that takes longer says so (report_progress)

_LOCK = threading.Lock()
_PROGRESS: list = []  # the stream report_progress set (at most one)


@contextlib.contextmanager
def report_progress(stream=None, after: float | None = None) -> Iterator[None]:
    """Within this block, every build that takes more than ``after`` seconds (default
    :data:`PROGRESS_AFTER_S`) writes ``arvcas: compiling <what> ...`` to ``stream`` (default standard
    error) when that time has passed, and the build's duration when it ends, on the same line."""
    entry = (stream if stream is not None else sys.stderr, PROGRESS_AFTER_S if after is None else float(after))
    with _LOCK:
        _PROGRESS.append(entry)
    try:
        yield
    finally:
        with _LOCK:
            _PROGRESS.remove(entry)


class Progress:
    """The progress line of one build (:func:`report_progress`); silent when none was asked for."""

    def __init__(self, what: str):
        self.what, self.shown, self.timer = what, False, None
        self.lock = threading.Lock()
        with _LOCK:
            self.sink = _PROGRESS[-1] if _PROGRESS else None

    def __enter__(self):
        self.t0 = time.perf_counter()
        if self.sink is not None:
            self.timer = threading.Timer(self.sink[1], self._start)
            self.timer.daemon = True
            self.timer.start()
        return self

    def _start(self) -> None:
        with self.lock:
            if self.timer is None:
                return
            self.shown = True
            self._write(f"arvcas: compiling {self.what} ...")

    def _write(self, text: str) -> None:
        try:
            self.sink[0].write(text)
            self.sink[0].flush()
        except (OSError, ValueError):  # a closed stream: progress is not worth an error
            pass

    def __exit__(self, exc_type, exc, tb) -> None:
        with self.lock:
            if self.timer is not None:
                self.timer.cancel()
                self.timer = None
            if self.shown:
                dt = time.perf_counter() - self.t0
                self._write(f" {dt:.1f} s\n" if exc_type is None else f" failed after {dt:.1f} s\n")
