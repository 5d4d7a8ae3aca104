"""The knees' tracked trajectories against the desired one (results/bluerov2_tracking/README.md).

    cd results/bluerov2_tracking && python tracking.py     # after `arvcas knees . --out knees`

Reads knees/knee_*.h5 (each stores its scenario) and writes tracking.png: the horizontal path (north x,
east y) of each knee beside the lawnmower, and x, y and pitch against time; prints each knee's RMSE against
eta_d(t_k) (docs/tasks.md) and its largest position error after the first 5 s.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from arvcas.io.results import read_result  # noqa: E402
from arvcas.sim import scenario  # noqa: E402

LAWS = ("proposed", "agsta", "pid")
COLORS = {"proposed": "#0072B2", "agsta": "#D55E00", "pid": "#009E73"}

runs = {c: read_result(f"knees/knee_{c}.h5") for c in LAWS}
cfg = scenario.loads_scenario(runs["proposed"].config_text)
t = runs["proposed"].t
eta_d = cfg.trajectory().sample(t)[0]
fig, ax = plt.subplots(1, 2, figsize=(7.0, 3.0))
ax[0].plot(eta_d[:, 1], eta_d[:, 0], "k--", lw=1.2, label="desired")
for c, r in runs.items():
    ax[0].plot(r.eta[:, 1], r.eta[:, 0], color=COLORS[c], lw=0.9, label=f"{c} knee")
ax[0].set_xlabel("east y (m)")
ax[0].set_ylabel("north x (m)")
ax[0].set_aspect("equal")
ax[0].legend(fontsize=7, loc="center")
ax[0].set_title("lawnmower, horizontal path", fontsize=8)
for c, r in runs.items():
    ax[1].plot(t, 100 * np.hypot(*(r.eta[:, :2] - eta_d[:, :2]).T), color=COLORS[c], lw=0.8, label=f"{c}: position")
    ax[1].plot(t, np.degrees(r.eta[:, 4] - eta_d[:, 4]), color=COLORS[c], lw=0.8, ls=":", label=f"{c}: pitch")
ax[1].set_xlabel("t (s)")
ax[1].set_ylabel("horizontal error (cm), pitch error (deg)")
ax[1].legend(fontsize=6, ncol=2)
ax[1].set_title("tracking error against eta_d(t)", fontsize=8)
fig.tight_layout()
fig.savefig("tracking.png", dpi=200)
print("knee       RMSE x, y, z (m)          RMSE phi, theta, psi (deg)   max |xy error| after 5 s (m)")
late = t >= 5.0
for c, r in runs.items():
    e = r.eta - eta_d
    print(f"{c:9s}  {np.round(r.rmse[:3], 4)}  {np.round(np.degrees(r.rmse[3:]), 2)}  "
          f"{np.hypot(*e[late, :2].T).max():.3f}")
