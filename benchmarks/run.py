"""Run the arvcas benchmark: the same as ``arvcas bench`` (arguments are passed on).

    python benchmarks/run.py                 # full: writes results/bench.json and results/bench.md
    python benchmarks/run.py --quick --out /tmp/bench
    python benchmarks/run.py --wait-load 0.3 # wait for a quiet machine first
"""

import sys

from arvcas.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
