"""A standalone harness of a general 6R arm's batch C, for A/B timing and per-function profiles
(issue 31): writes, into the current folder, the arm's kernel with a main that times
``<id>_ik_batch_general`` on 2000 configurations within the limits (``whole.c``, the main of
benchmarks/bench_general6r_eig.py), its header, ``poses.bin``, the C backend's flags
(``flags.txt``) and the batch function's name (``batch.txt``).

    .venv/bin/python benchmarks/profile_general6r_c.py crx10ia [--seed S]
    gcc $(cat flags.txt) -w -DG6B_BATCH=$(cat batch.txt) -o whole whole.c -lm
    ./whole poses.bin 7                    # poses, CPU seconds per pose (best of 7)

For a profile per function add ``-g -fno-inline-functions -fno-inline-small-functions
-fno-inline-functions-called-once`` and run ``perf record ./whole poses.bin 20``. Build two trees'
harnesses and run them interleaved for an A/B in one session.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from bench_general6r_eig import _HEAD, _MAIN
from derive import reference
from derive.codegen.emit import render_kernels
from derive.codegen.loader import c_flags
from derive.model.robot import load_robot


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("robot")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--poses", type=int, default=2000)
    args = ap.parse_args()
    r = load_robot(args.robot)
    rng = np.random.default_rng(args.seed)
    lo = np.maximum(r.limits[:, 0], -np.pi)
    hi = np.minimum(r.limits[:, 1], np.pi)
    poses = np.ascontiguousarray(reference.fk(r, rng.uniform(lo, hi, (args.poses, 6))), dtype=np.float64)
    files = render_kernels(r)
    _, src = files["c_source"]
    name, hdr = files["c_header"]
    Path(name).write_text(hdr)
    Path("poses.bin").write_bytes(poses.tobytes())
    Path("whole.c").write_text(_HEAD + src + _MAIN)
    Path("batch.txt").write_text(re.search(r"void (\w+_ik_batch_general)\(", src).group(1))
    Path("flags.txt").write_text(" ".join(c_flags()))
    print(f"wrote whole.c, {name}, poses.bin ({len(poses)} poses), flags.txt, batch.txt")


if __name__ == "__main__":
    main()
