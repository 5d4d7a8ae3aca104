#!/usr/bin/env bash
# Regenerates results/beyond (README.md there says what the files show). Measured on the 2-core
# machine, sharing it with other jobs: the Table 2 part (sweeps, 4 x 500 Monte Carlo runs, compares)
# about 7 min with a warm compile cache (+ about 4 min for 16 compiles of the traced run when cold);
# the fronts part (2 x 500 knee runs, 69 + 80 front members and Table 2 x 50 draws) about 8 min.
# (Those times are at h_plant = 0.01 s; at the default 0.05 s all of it took 2 min 36 s, cache warm.)
# FRONTS=DIR points the second part at another copy of the paper study's output.
set -euo pipefail
cd "$(dirname "$0")/../.."
B=results/beyond
mkdir -p "$B/mc" "$B/knee" "$B/robust"

# 1-2. sampling-period sweep (every controller, Table 2 gains), with and without sensor noise
arvcas sweep --h 0.02,0.05,0.1,0.2 --seeds 0..9 --out "$B/sweep"
arvcas sweep --h 0.02,0.05,0.1,0.2 --seeds 0 --noise-scale 0 --out "$B/sweep_noisefree"

# 3. Monte Carlo of every controller at its Table 2 gains, one master seed: the same draws for all
for c in proposed agsta traditional implicit; do
  arvcas montecarlo --controller "$c" --runs 500 --seed 2021 --out "$B/mc/$c.h5"
done
arvcas compare "$B/mc/proposed.h5" "$B/mc/agsta.h5" --report "$B/mc/proposed_vs_agsta.md" --plot "$B/mc/proposed_vs_agsta.png"
arvcas compare "$B/mc/implicit.h5" "$B/mc/proposed.h5" --report "$B/mc/implicit_vs_proposed.md" --plot "$B/mc/implicit_vs_proposed.png"
arvcas compare "$B/mc/traditional.h5" "$B/mc/proposed.h5" --report "$B/mc/traditional_vs_proposed.md" --plot "$B/mc/traditional_vs_proposed.png"

# 4-5. the knee points and the robustness of the fronts of the `paper` study
#      (results/tuning/paper from: arvcas tune studies/paper.toml --out results/tuning/paper)
F=${FRONTS:-results/tuning/paper}
for c in proposed agsta; do
  arvcas montecarlo --from-front "$F/$c" --index knee --runs 500 --seed 2021 --out "$B/knee/$c.h5"
  arvcas front robust "$F/$c" --runs 50 --seed 2021 --out "$B/robust/$c"
done
arvcas compare "$B/knee/proposed.h5" "$B/knee/agsta.h5" --report "$B/knee/proposed_vs_agsta.md" --plot "$B/knee/proposed_vs_agsta.png"
arvcas compare "$B/knee/proposed.h5" "$B/mc/proposed.h5" --report "$B/knee/proposed_knee_vs_table2.md" --plot "$B/knee/proposed_knee_vs_table2.png"
arvcas compare "$B/knee/agsta.h5" "$B/mc/agsta.h5" --report "$B/knee/agsta_knee_vs_table2.md" --plot "$B/knee/agsta_knee_vs_table2.png"
arvcas compare "$B/robust/proposed/robust.h5" "$B/robust/agsta/robust.h5" --report "$B/robust/proposed_vs_agsta.md" --plot "$B/robust/proposed_vs_agsta.png"
