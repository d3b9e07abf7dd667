"""Time of the whole UR3 derivation (issue: under 60 s on the 2-core machine).

Run: python benchmarks/bench_derivation.py [--robot ur3] [--repeats 5]
(the same as `dq-derive bench derivation`).
"""

import sys

from derive.bench.runner import main

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
