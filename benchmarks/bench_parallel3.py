"""The three-parallel class on the Unitree Z1 (derive.ik.parallel3): agreement with ssik's prebuilt
Z1 (IK-Geo's three parallel) and speed, on poses of configurations drawn within the joint limits.

    .venv/bin/python benchmarks/bench_parallel3.py [--n 10000] [--seed 0] [--json out.json]

Reports, for the numpy reference (derive.reference.ik_batch) and the C kernels
(derive.kernels("z1", "c").ik): how many poses have the same solution set as ssik (solve with
respect_limits=False, every 2 pi winding matched within 1e-9 rad), how often the generating
configuration is among the solutions (within 1e-9 rad, and within 1e-6 rad), the largest FK error
of any solution (m, rad), and the time per pose; ssik's time per pose (its native solver, one
pose per call, as it is called) in the same run. ssik needs the test or bench extra.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

import derive
from derive import dualquat as DQ
from derive import reference


def _wrapped(a, b):
    return np.abs((a - b + math.pi) % (2 * math.pi) - math.pi)


def _same_set(a, b, tol=1e-9) -> bool:
    a, b = np.asarray(a).reshape(-1, 6), np.asarray(b).reshape(-1, 6)
    if len(a) != len(b):
        return False
    if not len(a):
        return True
    return all(_wrapped(x, b).max(-1).min() < tol for x in a) and all(_wrapped(y, a).max(-1).min() < tol for y in b)


def _stats(robot, sols, counts, q, poses, theirs) -> dict:
    rows = np.concatenate([sols[i, :counts[i]] for i in range(len(q))])
    dp, dr = reference.pose_error(reference.fk(robot, rows), np.repeat(poses, counts, axis=0))
    gen = np.array([_wrapped(sols[i, :counts[i]], q[i]).max(-1).min() if counts[i] else np.inf
                    for i in range(len(q))])
    same = sum(_same_set(sols[i, :counts[i]], theirs[i]) for i in range(len(q)))
    return {"same_set_as_ssik": int(same), "generating_1e-9": int(np.sum(gen < 1e-9)),
            "generating_1e-6": int(np.sum(gen < 1e-6)), "largest_generating_gap_rad": float(gen.max()),
            "max_fk_error_m": float(dp.max()), "max_fk_error_rad": float(dr.max()),
            "counts": {int(k): int(v) for k, v in zip(*np.unique(counts, return_counts=True))}}


def _best_of(f, repeat=5) -> float:
    best = math.inf
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from ssik.prebuilt.unitree import z1_ik

    robot = derive.load_robot("z1")
    rng = np.random.default_rng(args.seed)
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], size=(args.n, 6))
    poses = reference.fk(robot, q)
    mats = DQ.to_matrix(poses)
    print(f"Unitree Z1, {args.n} poses of configurations within the limits (seed {args.seed})", flush=True)

    t = time.perf_counter()
    theirs = [[s.q for s in z1_ik.solve(m, respect_limits=False)] for m in mats]
    t_ssik = time.perf_counter() - t

    reference.ik_batch(robot, poses[:10])
    t_ref = _best_of(lambda: reference.ik_batch(robot, poses), 3)
    ref_sols, ref_counts = reference.ik_batch(robot, poses)

    # the UR5's numpy reference on its own 10^4 poses, for scale (the same FK check and merge)
    ur5 = derive.load_robot("ur5")
    ur5_poses = reference.fk(ur5, rng.uniform(-math.pi, math.pi, size=(args.n, 6)))
    t_ur5 = _best_of(lambda: reference.ik_batch(ur5, ur5_poses), 3)
    k5 = derive.kernels("ur5", "c")
    t_ur5c = _best_of(lambda: k5.ik(ur5_poses))

    k = derive.kernels("z1", "c")
    t_c = _best_of(lambda: k.ik(poses))
    c_sols, c_counts = k.ik(poses)
    kn = derive.kernels("z1", "numpy")
    t_np = _best_of(lambda: kn.ik(poses), 3)

    out = {"n": args.n, "seed": args.seed,
           "reference": {**_stats(robot, ref_sols, ref_counts, q, poses, theirs), "us_per_pose": 1e6 * t_ref / args.n},
           "c_kernels": {**_stats(robot, c_sols, c_counts, q, poses, theirs), "ns_per_pose": 1e9 * t_c / args.n},
           "numpy_kernels": {"us_per_pose": 1e6 * t_np / args.n},
           "ur5_for_scale": {"reference_us_per_pose": 1e6 * t_ur5 / args.n, "c_ns_per_pose": 1e9 * t_ur5c / args.n},
           "ssik": {"us_per_pose": 1e6 * t_ssik / args.n,
                    "counts": {int(a): int(b) for a, b in zip(*np.unique([len(x) for x in theirs], return_counts=True))}}}
    for name in ("reference", "c_kernels"):
        s = out[name]
        print(f"{name}: same set as ssik {s['same_set_as_ssik']}/{args.n}; generating configuration found "
              f"{s['generating_1e-9']}/{args.n} within 1e-9 rad, {s['generating_1e-6']}/{args.n} within 1e-6 "
              f"(largest gap {s['largest_generating_gap_rad']:.2g} rad); largest FK error "
              f"{s['max_fk_error_m']:.2g} m, {s['max_fk_error_rad']:.2g} rad; counts {s['counts']}")
    print(f"time per pose: numpy reference {out['reference']['us_per_pose']:.2f} us (batch), C kernels "
          f"{out['c_kernels']['ns_per_pose']:.0f} ns (batch), numpy kernels {out['numpy_kernels']['us_per_pose']:.2f} us "
          f"(batch), ssik {out['ssik']['us_per_pose']:.2f} us (one pose per call); for scale, the UR5 in the same run: "
          f"numpy reference {out['ur5_for_scale']['reference_us_per_pose']:.2f} us, C kernels "
          f"{out['ur5_for_scale']['c_ns_per_pose']:.0f} ns")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
