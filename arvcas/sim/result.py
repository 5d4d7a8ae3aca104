"""One closed-loop run's outcome: :class:`Result` (the traced signals, the metrics, the provenance).

:meth:`arvcas.sim.run.CompiledRun.simulate` builds it; :mod:`arvcas.sim.simulation` re-exports it beside
the thin wrappers; :mod:`arvcas.io.results` stores it.
"""

from __future__ import annotations

import numpy as np

from arvcas._version import __version__
from arvcas.controllers import gains as gains_mod
from arvcas.sim import signals as signals_mod

__all__ = ["Result"]


class Result:
    """One closed-loop run: the traced signals at the controller samples, the metrics, the provenance.

    Every traced signal (:mod:`arvcas.sim.signals`: ``t``, ``eta``, ``nu``, ``eta_hat``, ``eta_ref``,
    ``tau_cmd``, ``thrust``, ``f_true``, ``q``, ``payload`` and the controller's own, e.g. ``s``,
    ``k1``, ``k2``, ``f_hat``) is an attribute and an item (``r.eta``, ``r["eta"]``), an array of shape
    (N+1,) or (N+1, width) over samples t_k = k h, k = 0..N, in the signal's units and frame
    (``r.signals`` describes them). ``chat`` (eq. 42) and ``rmse`` (eq. 43) have shape (6,);
    ``chat_delivered`` (6,) is eq. 42 on the thrusters' delivered wrench (docs/model.md §6; None for a
    result read from a file written before it existed).
    """

    FIELDS = ("controller", "gains", "seed", "chat", "rmse", "ok", "t_fail", "config_text", "params_vector",
              "uncertainty", "phase", "h", "version", "meta", "chat_delivered")

    def __init__(self, controller: str, gains, seed: int, chat, rmse, ok: bool, t_fail: float | None,
                 config_text: str = "", params_vector=None, uncertainty=None, phase=None, h: float = 0.1,
                 version: str = __version__, meta: dict | None = None, signals=None, series: dict | None = None,
                 chat_delivered=None, **named_series):
        given = locals()
        self.__dict__.update({k: given[k] for k in self.FIELDS})
        self.meta = {} if meta is None else meta
        self.series: dict[str, np.ndarray] = {**(series or {}), **named_series}
        if signals is None:  # the registered controller's signals (or the common ones)
            try:
                signals = signals_mod.trace_signals(gains_mod.get(controller))
            except ValueError:
                signals = signals_mod.COMMON
        self.signals = tuple(s for s in signals if s.name in self.series)
        order = [s.name for s in self.signals]  # series in signal-table order, then any undescribed ones
        self.series = {k: self.series[k] for k in order + [k for k in self.series if k not in order]}

    def __getattr__(self, name: str):
        series = self.__dict__.get("series")
        if series is not None and name in series:
            return series[name]
        raise AttributeError(f"Result has no attribute or signal {name!r}"
                             + (f" (signals: {', '.join(series)})" if series else ""))

    def __setattr__(self, name: str, value) -> None:
        series = self.__dict__.get("series")
        if series is not None and name in series:
            series[name] = value
        else:
            object.__setattr__(self, name, value)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.series[name]

    @property
    def e(self) -> np.ndarray:
        """Tracking error eta - eta_ref (the RMSE's e, eq. 43)."""
        return self.eta - self.eta_ref

    @property
    def diverged(self) -> bool:
        return not self.ok

    @property
    def duration(self) -> float:
        t = self.series.get("t")
        return float(t[-1]) if t is not None and len(t) else 0.0

    def __repr__(self) -> str:
        status = "ok" if self.ok else f"diverged at t = {self.t_fail:g} s" + (
            f" ({self.meta['failure']})" if self.meta.get("failure") else "")
        fmt = lambda v: "[" + ", ".join(f"{x:.3g}" for x in np.asarray(v, dtype=float).ravel()) + "]"  # noqa: E731
        chat, rmse = fmt(self.chat), fmt(self.rmse)
        return (f"<Result {self.controller}, seed {self.seed}, {self.duration:g} s, {status}; "
                f"CHAT {chat}, RMSE {rmse}>")
