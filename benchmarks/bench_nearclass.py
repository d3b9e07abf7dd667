"""Near-class arms (issue 30, item 3): the numpy reference's nominal closed form + Newton polish
on 10^4 poses per arm, configurations uniform within the joint limits (+-2 pi where wider).

For each arm: the time of ``derive.ik.nearclass.ik_batch`` (the nominal found first, not timed),
the solution counts, the largest residual after the polish (max of position error m and rotation
angle rad), the largest FK error of the solutions checked independently (derive.reference.fk,
the dual-quaternion product), how often the generating configuration is among the solutions
(within 1e-6 rad, modulo 2 pi), the candidates dropped (did not converge) and the Newton steps.
Configurations within 1e-3 rad of the wrist singularity are left out (a near-continuum of
solutions there), except with --all.

``--kernels c|numpy|python``: the emitted near-class kernels (``derive.kernels(arm, backend[,
free="q3"]).ik_polish``, derive.codegen.polish) instead of the numpy reference, on the same poses;
the first use derives and compiles them (not timed). ``--compare`` also runs the numpy reference
on the poses and counts the poses whose solution sets differ (a solution of one without one of the
other within 1e-6 rad in every joint, modulo 2 pi).

Run: python benchmarks/bench_nearclass.py [--n 10000] [--seed 1] [--clip 6.283] [--all]
     [--only NAME] [--kernels c|numpy|python] [--compare]

The kernels' measurement of issue 30 item 3 (uniform within the limits clipped to +-pi, seed 5,
every configuration):

    python benchmarks/bench_nearclass.py --kernels c --seed 5 --clip 3.14159265 --all --compare
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import derive
from derive import reference
from derive.ik import nearclass
from derive.kinematics.fk import pose_error

DATA = Path(__file__).resolve().parent.parent / "tests" / "data"
CASES_ALL = [("PUMA 560 URDF, twists 1.570796325", str(DATA / "puma560-printed.urdf"), None),
         ("UR5, alpha 1.5708", str(DATA / "ur5-decimal.yaml"), None),
         ("iiwa14 URDF, axes 0.44 mm off, q3 given", str(DATA / "iiwa14-off.urdf"), 2),
         ("UR5 calibrated (nominal: ur5)", "ur5-calibrated", None),
         ("Kinova Gen3, q3 given", "gen3", 2)]
CASES = CASES_ALL


def _wrap(d):
    return (np.asarray(d) + np.pi) % (2 * np.pi) - np.pi


def _solve(robot, poses, free, kernels):
    """(q (n, w, dof) NaN-padded, counts (n,), residual (n, w), Newton steps (n, w), dropped or
    None) of the numpy reference (kernels None) or of the emitted kernels."""
    if kernels is None:
        r = (nearclass.ik_batch(robot, poses) if free is None
             else nearclass.ik_batch(robot, poses, free=free, free_name="q3"))
        return r.q, r.counts, r.residual, r.iterations, r.dropped
    k = derive.kernels(robot, kernels, **({} if free is None else {"free": "q3"}))
    sols, counts, res, its = k.ik_polish(poses) if free is None else k.ik_polish(poses, free)
    return sols, counts, res, its, None


def _differ(a, ca, b, cb) -> np.ndarray:
    """Per pose: whether the solution sets a[:ca] and b[:cb] differ (a row of one without a row of
    the other within 1e-6 rad in every joint, modulo 2 pi)."""
    out = np.zeros(len(a), dtype=bool)
    for i in range(len(a)):
        x, y = a[i, :ca[i]], b[i, :cb[i]]
        if len(x) != len(y):
            out[i] = True
            continue
        if len(x) == 0:
            continue
        d = np.abs(_wrap(x[:, None] - y[None])).max(-1) < 1e-6
        out[i] = not (d.any(1).all() and d.any(0).all())
    return out


def run(n: int, seed: int, only: str | None = None, clip: float = 2 * np.pi, keep_all: bool = False,
        kernels: str | None = None, compare: bool = False) -> None:
    print(f"solver: {'numpy reference (derive.ik.nearclass.ik_batch)' if kernels is None else kernels + ' kernels'}"
          f"; configurations uniform within the limits clipped to +-{clip:g}, seed {seed}"
          f"{'' if keep_all else ', |sin q_wrist| > 1e-3'}; load average {os.getloadavg()[0]:.2f}")
    print(f"{'arm':<42} {'poses':>6} {'time s':>7} {'us/pose':>8} {'max residual':>12} "
          f"{'max FK err':>10} {'gen. found':>10} {'dropped':>7} {'steps mean/max':>14}"
          + (f"{'differ':>7}" if compare else "") + "  counts")
    for label, name, given in [c for c in CASES if only is None or only in c[1]]:
        robot = derive.load_robot(name)
        nom = nearclass.nominal(robot)
        if nom is None:     # an exact class now (the UR5 with alpha 1.5708 is of the three-parallel class)
            print(f"{label:<42} exact class {nearclass.exact_class(robot)}: no nominal, solved exactly")
            continue
        lo, hi = robot.limits.T
        q = np.random.default_rng(seed).uniform(np.maximum(lo, -clip), np.minimum(hi, clip), (2 * n, robot.dof))
        if not keep_all:
            wrist = 4 if robot.dof == 6 else 5
            q = q[np.abs(np.sin(q[:, wrist])) > 1e-3]
        q = q[:n]
        poses = reference.fk(robot, q)
        free = None if given is None else q[:, given]
        if kernels is not None:
            _solve(robot, poses[:4], None if free is None else free[:4], kernels)   # derive/compile, not timed
        t0 = time.perf_counter()
        sols, counts, residual, its, dropped = _solve(robot, poses, free, kernels)
        dt = time.perf_counter() - t0
        rows = ~np.isnan(sols[..., 0])
        flat = sols[rows]
        dp, dr = pose_error(reference.fk(robot, flat), np.repeat(poses, sols.shape[1], axis=0)[rows.reshape(-1)])
        found = sum(bool(counts[i]) and bool((np.abs(_wrap(sols[i, :counts[i]] - q[i])).max(1) < 1e-6).any())
                    for i in range(len(q)))
        steps = its[rows]
        diff = ""
        if compare:
            ref = _solve(robot, poses, free, None)
            diff = f" {int(_differ(sols, counts, ref[0], ref[1]).sum()):>6}"
        print(f"{label:<42} {len(q):>6} {dt:>7.2f} {1e6 * dt / len(q):>8.0f} {np.nanmax(residual):>12.1e} "
              f"{max(dp.max(), dr.max()):>10.1e} {found:>5}/{len(q):<4} "
              f"{'-' if dropped is None else int(dropped.sum()):>7} "
              f"{steps.mean():>7.2f}/{steps.max():<6}{diff} {np.bincount(counts, minlength=9).tolist()}"
              f"  (nominal {nom.robot.name}, deviation {nom.deviation:.2g})", flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--clip", type=float, default=2 * np.pi, help="the limits clipped to +-CLIP (rad)")
    ap.add_argument("--all", action="store_true", help="keep the configurations near the wrist singularity")
    ap.add_argument("--only", default=None, help="only the arms whose file name contains this")
    ap.add_argument("--kernels", choices=("c", "numpy", "python"), default=None,
                    help="the emitted near-class kernels of this backend instead of the numpy reference")
    ap.add_argument("--compare", action="store_true", help="count the poses whose sets differ from the reference's")
    a = ap.parse_args()
    run(a.n, a.seed, a.only, a.clip, a.all, a.kernels, a.compare)
