"""Measure the shipped Hinsdale 2023 trials: per trial and stream the rows, duration, mean rate, longest gap
and non-finite entries; the roll and pitch ranges (IMU quaternion and motion capture, ZYX Euler angles of
the logged body-to-world quaternions, the dataset's own z-up convention) and the joints' travel.

    python studies/validation/hinsdale2023/measure.py            # the table of README.md, as Markdown

NumPy only; reads the files as shipped (numpy.loadtxt reads .gz). Motion-capture rows whose roll or pitch
exceed 30 degrees are the capture system's pose flips (README.md, "Streams"): counted, and left out of the
motion-capture range.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
IDENTIFY = ("traj003-0", "traj005-0", "traj012-1", "traj019-2", "traj024-1", "traj030-0")
HELD_OUT = ("traj006-3", "traj014-2", "traj024-2")
BASELINES = ("baseline1", "baseline2", "baseline3")
STREAMS = ("mocap", "imu", "joint_states")
FLIP = np.radians(30.0)


def read(trial: str, stream: str) -> tuple[list[str], np.ndarray]:
    """The stream's header and its rows (float array) as shipped."""
    path = HERE / f"{trial}_{stream}.csv.gz"
    with __import__("gzip").open(path, "rt") as fh:
        header = fh.readline().strip().split(",")
    return header, np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def roll_pitch(header: list[str], a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ZYX roll and pitch (rad) of the body-to-world quaternion columns x_ori, y_ori, z_ori, w_ori."""
    x, y, z, w = (a[:, header.index(c)] for c in ("x_ori", "y_ori", "z_ori", "w_ori"))
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    return roll, pitch


def measure(trial: str) -> dict:
    out: dict = {"trial": trial}
    for s in STREAMS:
        h, a = read(trial, s)
        t = a[:, 0]
        dt = np.diff(t)
        out[s] = {"rows": len(t), "t0": t[0], "t1": t[-1], "rate": (len(t) - 1) / (t[-1] - t[0]),
                  "gap": dt.max(), "nonfinite": int((~np.isfinite(a)).sum()), "increasing": bool((dt > 0).all())}
        if s in ("mocap", "imu"):
            r, p = roll_pitch(h, a)
            keep = (np.abs(r) < FLIP) & (np.abs(p) < FLIP)
            out[s]["flips"] = int((~keep).sum())
            out[s]["roll"] = np.degrees([r[keep].min(), r[keep].max()])
            out[s]["pitch"] = np.degrees([p[keep].min(), p[keep].max()])
        else:
            q = a[:, [h.index(f"axis_{j}_pos") for j in "edcb"]]
            out[s]["travel"] = q.max(0) - q.min(0)
    return out


def role(trial: str) -> str:
    return "identify" if trial in IDENTIFY else "held out" if trial in HELD_OUT else "baseline"


def table(trials=IDENTIFY + HELD_OUT + BASELINES) -> str:
    rows = ["| trial | role | stream | rows | span (s) | mean rate (Hz) | longest gap (s) | notes |",
            "|---|---|---|---|---|---|---|---|"]
    for tr in trials:
        m = measure(tr)
        for s in STREAMS:
            d = m[s]
            note = []
            if d["nonfinite"]:
                note.append(f"{d['nonfinite']} non-finite")
            if not d["increasing"]:
                note.append("time not increasing")
            if s in ("mocap", "imu"):
                note.append(f"roll {d['roll'][0]:.1f} .. {d['roll'][1]:.1f} deg, pitch {d['pitch'][0]:.1f} .. "
                            f"{d['pitch'][1]:.1f} deg")
                if d["flips"]:
                    note.append(f"{d['flips']} pose flips")
            else:
                note.append("travel e d c b " + " ".join(f"{x:.2f}" for x in d["travel"]) + " rad")
            rows.append(f"| {tr if s == 'mocap' else ''} | {role(tr) if s == 'mocap' else ''} | {s} | {d['rows']} | "
                        f"{d['t0']:.2f} .. {d['t1']:.2f} | {d['rate']:.1f} | {d['gap']:.3f} | {'; '.join(note)} |")
    return "\n".join(rows)


if __name__ == "__main__":
    sys.stdout.write(table() + "\n")
