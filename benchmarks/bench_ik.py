"""Reference IK time per pose (batch and single call). Same as `dq-derive bench ik`."""

import sys

from derive.bench.runner import main

if __name__ == "__main__":
    sys.exit(main(["ik"] + sys.argv[1:]))
