"""``python -m arvcas.bench [--quick] [--out DIR] [--wait-load X]``: the same as ``arvcas bench``."""

import sys

from arvcas.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
