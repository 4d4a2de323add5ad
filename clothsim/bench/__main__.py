"""``python -m clothsim.bench``: the benchmark without the app's other commands (the same options
as ``python app.py bench``)."""

import argparse
import sys

from . import GARMENT_REPEAT, main

if __name__ == "__main__":  # pragma: no cover
    p = argparse.ArgumentParser()
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", default="docs/benchmarks")
    p.add_argument("--scans", action="store_true")
    p.add_argument("--garments", action="store_true")
    p.add_argument("--repeat", type=int, default=GARMENT_REPEAT)
    p.add_argument("--surface", default="faceted", choices=("faceted", "smooth"))
    sys.exit(main(p.parse_args()))
