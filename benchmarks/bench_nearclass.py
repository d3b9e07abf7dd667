"""Near-class arms (issue 30, item 3): the numpy reference's nominal closed form + Newton polish
on 10^4 poses per arm, configurations uniform within the joint limits (+-2 pi where wider).

For each arm: the time of ``derive.ik.nearclass.ik_batch`` (the nominal found first, not timed),
the solution counts, the largest residual after the polish (max of position error m and rotation
angle rad), the largest FK error of the solutions checked independently (derive.reference.fk,
the dual-quaternion product), how often the generating configuration is among the solutions
(within 1e-6 rad, modulo 2 pi), the candidates dropped (did not converge) and the Newton steps.
Configurations within 1e-3 rad of the wrist singularity are left out (a near-continuum of
solutions there).

Run: python benchmarks/bench_nearclass.py [--n 10000] [--seed 1] [--only NAME]
"""

from __future__ import annotations

import argparse
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


def run(n: int, seed: int, only: str | None = None) -> None:
    print(f"{'arm':<42} {'poses':>6} {'time s':>7} {'us/pose':>8} {'max residual':>12} "
          f"{'max FK err':>10} {'gen. found':>10} {'dropped':>7} {'steps mean/max':>14}  counts")
    for label, name, given in [c for c in CASES if only is None or only in c[1]]:
        robot = derive.load_robot(name)
        nom = nearclass.nominal(robot)
        if nom is None:     # an exact class now (the UR5 with alpha 1.5708 is of the three-parallel class)
            print(f"{label:<42} exact class {nearclass.exact_class(robot)}: no nominal, solved exactly")
            continue
        lo, hi = robot.limits.T
        q = np.random.default_rng(seed).uniform(np.maximum(lo, -2 * np.pi), np.minimum(hi, 2 * np.pi),
                                                (2 * n, robot.dof))
        wrist = 4 if robot.dof == 6 else 5
        q = q[np.abs(np.sin(q[:, wrist])) > 1e-3][:n]
        poses = reference.fk(robot, q)
        t0 = time.perf_counter()
        if given is None:
            r = nearclass.ik_batch(robot, poses)
        else:
            r = nearclass.ik_batch(robot, poses, free=q[:, given], free_name="q3")
        dt = time.perf_counter() - t0
        rows = ~np.isnan(r.q[..., 0])
        sols = r.q[rows]
        dp, dr = pose_error(reference.fk(robot, sols), np.repeat(poses, r.q.shape[1], axis=0)[rows.reshape(-1)])
        found = sum(bool(r.counts[i]) and bool((np.abs(_wrap(r.q[i, :r.counts[i]] - q[i])).max(1) < 1e-6).any())
                    for i in range(len(q)))
        its = r.iterations[rows]
        print(f"{label:<42} {len(q):>6} {dt:>7.2f} {1e6 * dt / len(q):>8.0f} {np.nanmax(r.residual):>12.1e} "
              f"{max(dp.max(), dr.max()):>10.1e} {found:>5}/{len(q):<4} {int(r.dropped.sum()):>7} "
              f"{its.mean():>7.2f}/{its.max():<6} {np.bincount(r.counts, minlength=9).tolist()}"
              f"  (nominal {nom.robot.name}, deviation {nom.deviation:.2g})")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", default=None, help="only the arms whose file name contains this")
    a = ap.parse_args()
    run(a.n, a.seed, a.only)
