"""The figure of docs/ik.md's "General 6R arms" section: the 16 IK solutions of one pose of the
Fanuc CRX-10iA (derive/robots/crx10ia.yaml), each drawn as a stick figure reaching the same pose
(derive.reports.figures.ik_figure, the drawing of `dq-derive plot --ik-of`).

    .venv/bin/python benchmarks/figure_general6r.py [--out docs/figures/crx10ia_16_solutions.png]

The configuration is the first of a seeded random draw within the limits (rounded to 0.1 degree)
whose pose has 16 solutions; the script prints it and the solutions' largest FK error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import derive
from derive import reference
from derive.ik import general6r
from derive.reports.figures import ik_figure


def sixteen(robot, seed=16, n=4000):
    """A configuration within the limits, in whole tenths of a degree, with 16 solutions."""
    rng = np.random.default_rng(seed)
    q = np.deg2rad(np.round(np.rad2deg(rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (n, 6))), 1))
    res = general6r.solve(robot, reference.fk(robot, q))
    hits = np.nonzero(res.counts == 16)[0]
    if len(hits) == 0:
        raise SystemExit("no configuration with 16 solutions in the draw; raise n")
    return q[hits[0]]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("docs/figures/crx10ia_16_solutions.png"))
    a = ap.parse_args(argv)
    robot = derive.load_robot("crx10ia")
    q = sixteen(robot)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    sols, _ = ik_figure(robot, q, a.out, deg=True)
    # a 256-colour palette (the drawing has few colours): a third of the bytes in the repository
    from PIL import Image
    Image.open(a.out).convert("RGB").quantize(256, method=Image.Quantize.FASTOCTREE).save(a.out, optimize=True)
    err = np.abs(reference.fk_matrix(robot, sols) - reference.fk_matrix(robot, q)).max()
    print(f"crx10ia at q = {np.round(np.rad2deg(q), 1).tolist()} deg: {len(sols)} solutions, "
          f"largest FK error {err:.1e}; wrote {a.out}")
    for s in sols:
        print("  " + " ".join(f"{v:8.2f}" for v in np.rad2deg(s)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
