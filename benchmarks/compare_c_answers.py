"""The C kernels' whole answers, to compare two trees bit for bit (issue 31's same-bits checks):
the general 6R batch (``<id>_ik_batch_general``: solutions, counts, singular and degenerate flags)
of crx10ia, xarm6, jaco2-6dof and general-6r on N random configurations within the limits, and
``k.ik(P, free=values)`` of five seven-joint plans (xarm7 q1 and q3, gen3 q4 and q6, panda q5) on
N / 4.

    PYTHONPATH=TREE DQ_DERIVE_CACHE=SCRATCH .venv/bin/python benchmarks/compare_c_answers.py OUT.npz [N]
    .venv/bin/python benchmarks/compare_c_answers.py --cmp A.npz B.npz

Run the first line once per tree (each with its own scratch cache folder, so that neither loads
the other's kernels), then ``--cmp``: it names every array that differs in any bit and exits 1
if one does.
"""

from __future__ import annotations

import sys

import numpy as np

import derive
from derive import reference
from derive.codegen.general6r import c_ik_general
from derive.model.robot import load_robot

ARMS_6R = ("crx10ia", "xarm6", "jaco2-6dof", "general-6r")
PLANS_7R = (("xarm7", 1), ("xarm7", 3), ("gen3", 4), ("panda", 5), ("gen3", 6))


def _bits(x: np.ndarray) -> np.ndarray:
    return x.view(np.uint8) if x.dtype.kind == "f" else x


def compare(a_path: str, b_path: str) -> int:
    a, b = np.load(a_path), np.load(b_path)
    bad = [k for k in a.files if k not in b.files or a[k].shape != b[k].shape
           or not np.array_equal(_bits(a[k]), _bits(b[k]))]
    for k in bad:
        print("differs:", k)
    print(f"compared {len(a.files)} arrays, {len(bad)} differ")
    return int(bool(bad))


def _configurations(r, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo = np.maximum(r.limits[:, 0], -np.pi)
    hi = np.minimum(r.limits[:, 1], np.pi)
    return rng.uniform(lo, hi, (n, len(lo)))


def dump(out: str, n: int) -> None:
    arrays = {}
    for name in ARMS_6R:
        r = load_robot(name)
        poses = reference.fk(r, _configurations(r, n, 1))
        sols, counts, sing, degen = c_ik_general(derive.kernels(name, "c"), poses)
        arrays.update({f"{name}_s": sols, f"{name}_c": counts, f"{name}_sg": sing, f"{name}_dg": degen})
    for name, joint in PLANS_7R:
        r = load_robot(name)
        q = _configurations(r, n // 4, 2)
        res = derive.kernels(name, "c", free=f"q{joint}").ik(reference.fk(r, q), free=q[:, joint - 1])
        for i, a in enumerate(res if isinstance(res, tuple) else (res,)):
            arrays[f"{name}_q{joint}_{i}"] = np.asarray(a)
    np.savez(out, **arrays)
    print(f"saved {len(arrays)} arrays to {out}")


if __name__ == "__main__":
    if len(sys.argv) >= 4 and sys.argv[1] == "--cmp":
        sys.exit(compare(sys.argv[2], sys.argv[3]))
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    dump(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 1000)
