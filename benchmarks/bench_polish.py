"""Near-class C kernels against the exact ones, in the same run: ns per pose of the batch IK and
the latency of one call (the CPython extension's ik), for the UR5 with its twists written 1.5708
(nominal: the library UR5; derive.codegen.polish) and the exact UR5 (shipped kernels).

    python benchmarks/bench_polish.py [n] [repeats]

Times are CPU time of this process (time.process_time), so that other work on the machine
does not count; the load average is printed with them.

The near-class kernels are derived into the user cache on first use (a minute: the UR5's IK
program and two C compiles)."""

import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import derive
from derive.ik.nearclass import Nominal

ROOT = Path(__file__).resolve().parents[1]


def decimal_ur5():
    text = (ROOT / "derive" / "robots" / "ur5.yaml").read_text()
    text = text.replace("name: ur5", "name: ur5-decimal").replace("-pi/2", "-1.5708").replace("pi/2", "1.5708")
    path = Path(tempfile.mkdtemp()) / "ur5-decimal.yaml"
    path.write_text(text)
    one = np.array([1.0, 0, 0, 0, 0, 0, 0, 0])
    return derive.load_robot(path), Nominal(derive.load_robot("ur5"), one, one, np.ones(6), np.zeros(6),
                                            abs(1.5708 - math.pi / 2), "by hand")


def measure(k, robot, n, repeats, single=2000, seed=0):
    rng = np.random.default_rng(seed)
    poses = derive.reference.fk(robot, rng.uniform(-math.pi, math.pi, size=(n, 6)))
    k.ik(poses[:64])                                           # warm-up
    batch = []
    for _ in range(repeats):
        t = time.process_time()
        _, counts = k.ik(poses)
        batch.append((time.process_time() - t) / n)
    lat = []
    for p in poses[:single]:
        t = time.process_time()
        k.ik(p)
        lat.append(time.process_time() - t)
    return min(batch) * 1e9, float(np.median(lat)) * 1e9, float(counts.mean())


def main(argv):
    n = int(argv[0]) if argv else 10_000
    repeats = int(argv[1]) if len(argv) > 1 else 5
    robot, nominal = decimal_ur5()
    near = derive.kernels(robot, "c", nominal=nominal)
    exact = derive.kernels("ur5", "c")
    print(f"load average {os.getloadavg()[0]:.2f} (CPU time per pose, time.process_time)")
    print(f"{'kernels':<28} {'batch ns/pose':>14} {'one call ns':>12} {'solutions':>10}")
    for name, k, r in (("ur5 (exact)", exact, derive.load_robot("ur5")), ("ur5-decimal (near-class)", near, robot),
                       ("ur5 (exact, again)", exact, derive.load_robot("ur5"))):
        b, one, sols = measure(k, r, n, repeats)
        print(f"{name:<28} {b:14.0f} {one:12.0f} {sols:10.2f}")
    _, counts, _, its = near.ik_polish(derive.reference.fk(robot, np.random.default_rng(1).uniform(
        -math.pi, math.pi, size=(n, 6))))
    filled = np.arange(8)[None, :] < counts[:, None]
    print("near-class Newton steps per solution:", np.bincount(its[filled]).tolist())
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
