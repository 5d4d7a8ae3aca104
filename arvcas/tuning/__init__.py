"""Controller tuning on the CHAT/RMSE Pareto front (docs/model.md §7) with pymoo's NSGA-II. No physics here.

* :mod:`.study`: strict TOML study files -> :class:`Study`;
* :mod:`.problem`: the vectorised pymoo Problem (log10 gains -> objectives, one constraint);
* :mod:`.engines`: ``local`` (all cores) and ``dask`` evaluation of a generation;
* :mod:`.checkpoint`: ``front.h5`` (atomic, resumable), the output-directory lock;
* :mod:`.run`: the ask/tell loop with progress, checkpoints, resume and SIGINT handling;
* :mod:`.front`: :class:`Front`, export (CSV/JSON), plot, knee point, replay of a member;
* :mod:`.compare`: two fronts against one reference point.
"""

import importlib

# name -> submodule; imported on first use so that `arvcas --help` does not load pymoo, h5py or dask
_EXPORTS = {
    "Study": "study", "StudyError": "study", "load_study": "study", "loads_study": "study",
    "GainProblem": "problem", "Evaluation": "problem", "INFEASIBLE_F": "problem",
    "EngineError": "engines", "CheckpointError": "checkpoint",
    "TuningError": "run", "Outcome": "run", "run_study": "run",
    "Front": "front", "read_front": "front", "export_front": "front", "plot_front": "front", "plot_fronts": "front",
    "knee_index": "front", "member_gains": "front", "replay": "front",
    "Comparison": "compare", "compare_fronts": "compare", "format_comparison": "compare",
}
__all__ = list(_EXPORTS)


def __getattr__(name: str):
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'arvcas.tuning' has no attribute {name!r}")
    return getattr(importlib.import_module(f".{mod}", __name__), name)
