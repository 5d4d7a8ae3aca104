"""Metrics: performance indices computed on a run's stored series (above the controllers and the
simulation, below tuning; docs/architecture.md).

:mod:`~arvcas.metrics.indices`: CHAT (eq. 42), RMSE (eq. 43), the paper's Table 3 and the
docs/model.md §7 normalised objectives. Its names are re-exported here (``arvcas.metrics.chat``).
"""

from arvcas.metrics.indices import DOFS, Table3, chat, normalised_objectives, rmse, table3

__all__ = ["chat", "rmse", "Table3", "table3", "normalised_objectives", "DOFS"]
