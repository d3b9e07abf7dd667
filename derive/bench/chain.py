"""The quaternion-versus-matrix claim of the Spanish quaternion course notes (the source listed
as seed 000 in docs/sources.md), measured (``dq-derive bench chain``).

Seed 000 claims that forward kinematics with quaternions is 3 to 5 times faster than with DH
matrices, with and without reuse of the partial products. Both methods compute every joint origin
O_1 .. O_n of an n-joint standard-DH chain (random numbers, one sin/cos pair per joint, alpha's
sines and cosines precomputed):

* quaternions as the seed writes them: O_k = Q_1..(k-1) (0, r_k) conj(Q_1..(k-1)) + O_(k-1),
  the sandwich as two Hamilton products;
* 4x4 matrices: T_0k = T_0(k-1) A_k, O_k its last column;
* "reuse": partial products carried from joint to joint; "scratch": recomputed for every k.

C: ``derive/data/bench_chain.c`` (compiled with the C backend's flags). numpy: the same
algorithms vectorised over a batch of configurations. Operation counts per the code below.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np

from derive.codegen.loader import c_compiler, c_flags

# multiplications / additions of the building blocks as coded (C and numpy alike)
QMUL = (16, 12)          # Hamilton product
MMUL = (64, 48)          # 4x4 product (the 0.0 start of each sum not counted)
JOINT_Q = (10, 1)        # Q_k = qz qx (4 mul), r_k by double angles (4 mul, 1 add) and a (2 mul)
JOINT_M = (6, 0)         # the DH matrix entries


def op_counts(n: int) -> dict:
    """Multiplications and additions (not counting sin/cos: n pairs in every method)."""
    def total(per):
        return sum(m for m, _ in per), sum(a for _, a in per)
    qr = [JOINT_Q] * n + [QMUL] * (3 * n) + [(0, 3)] * n                 # acc, sandwich (2), O +=
    qs = [JOINT_Q] * n + [QMUL] * (2 * n + n * (n - 1) // 2) + [(0, 3)] * n
    mr = [JOINT_M] * n + [MMUL] * n
    ms = [JOINT_M] * n + [MMUL] * (n * (n + 1) // 2)
    return {k: total(v) for k, v in (("quat_reuse", qr), ("quat_scratch", qs),
                                     ("matrix_reuse", mr), ("matrix_scratch", ms))}


def _qmul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def _mmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def origins_numpy(th, dh, method: str):
    """Joint origins (n, 3, batch) of a chain for joint values th (batch, n)."""
    b, n = th.shape
    cz, sz = np.cos(0.5 * th.T), np.sin(0.5 * th.T)
    out = []
    if method.startswith("quat"):
        qs = [(cz[k] * dh[k, 4], cz[k] * dh[k, 5], sz[k] * dh[k, 5], sz[k] * dh[k, 4]) for k in range(n)]
        rs = [(0.0, dh[k, 1] * (1.0 - 2.0 * sz[k] * sz[k]), dh[k, 1] * (2.0 * sz[k] * cz[k]),
               np.full(b, dh[k, 0])) for k in range(n)]
        acc = (np.ones(b), np.zeros(b), np.zeros(b), np.zeros(b))
        o = np.zeros((3, b))
        for k in range(n):
            if method == "quat_scratch":
                acc = (np.ones(b), np.zeros(b), np.zeros(b), np.zeros(b))
                for j in range(k):
                    acc = _qmul(acc, qs[j])
            t = _qmul(_qmul(acc, rs[k]), (acc[0], -acc[1], -acc[2], -acc[3]))
            o = o + np.array(t[1:])
            out.append(o)
            if method == "quat_reuse":
                acc = _qmul(acc, qs[k])
        return np.array(out)
    ct, st = np.cos(th.T), np.sin(th.T)
    z, one = np.zeros(b), np.ones(b)
    ms = [[[ct[k], -st[k] * dh[k, 2], st[k] * dh[k, 3], dh[k, 1] * ct[k]],
           [st[k], ct[k] * dh[k, 2], -ct[k] * dh[k, 3], dh[k, 1] * st[k]],
           [z, np.full(b, dh[k, 3]), np.full(b, dh[k, 2]), np.full(b, dh[k, 0])],
           [z, z, z, one]] for k in range(n)]
    eye = [[one if i == j else z for j in range(4)] for i in range(4)]
    acc = eye
    for k in range(n):
        if method == "matrix_scratch":
            acc = eye
            for j in range(k + 1):
                acc = _mmul(acc, ms[j])
        else:
            acc = _mmul(acc, ms[k])
        out.append(np.array([acc[0][3], acc[1][3], acc[2][3]]))
    return np.array(out)


def random_dh(n: int, seed: int = 7) -> np.ndarray:
    rng = np.random.default_rng(seed)
    al = rng.uniform(-3, 3, n)
    return np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), np.cos(al), np.sin(al),
                            np.cos(0.5 * al), np.sin(0.5 * al)])


def bench_chain_numpy(nmax: int = 50, batch: int = 2000, repeats: int = 3) -> list:
    rng = np.random.default_rng(1)
    rows = []
    for n in range(1, nmax + 1):
        dh = random_dh(n)
        th = rng.uniform(-3, 3, (batch, n))
        row = {"n": n}
        for method in ("quat_reuse", "quat_scratch", "matrix_reuse", "matrix_scratch"):
            best = float("inf")
            for _ in range(repeats):
                t = time.perf_counter()
                res = origins_numpy(th, dh, method)
                best = min(best, time.perf_counter() - t)
            row[f"{method}_ns"] = best / batch * 1e9
            row.setdefault("ref", res) if method == "quat_reuse" else None
        row["max_diff"] = float(np.abs(row.pop("ref") - origins_numpy(th, dh, "matrix_reuse")).max())
        rows.append(row)
    return rows


def bench_chain_c(nmax: int = 50, batch: int = 2000, repeats: int = 3) -> list:
    compiler = c_compiler()
    if compiler is None:
        return []
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "chain.c"
        src.write_text(resources.files("derive.data").joinpath("bench_chain.c").read_text())
        exe = Path(tmp) / "chain"
        subprocess.run([compiler, *c_flags(), "-o", str(exe), str(src), "-lm"], check=True,
                       capture_output=True, text=True)
        run = subprocess.run([str(exe), str(nmax), str(batch), str(repeats)], check=True,
                             capture_output=True, text=True)
    return [json.loads(line) for line in run.stdout.splitlines() if line.strip()]


def plot(c_rows: list, np_rows: list, path) -> None:
    """Time per configuration against the number of joints, C and numpy, log scale."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, rows, title in ((axes[0], c_rows, "C (one configuration per call)"),
                            (axes[1], np_rows, "numpy (batch of 2000 configurations)")):
        n = [r["n"] for r in rows]
        for key, label, style in (("quat_reuse", "quaternions, reuse", "C0-"),
                                  ("matrix_reuse", "4x4 matrices, reuse", "C1-"),
                                  ("quat_scratch", "quaternions, no reuse", "C0--"),
                                  ("matrix_scratch", "4x4 matrices, no reuse", "C1--")):
            ax.plot(n, [r[f"{key}_ns"] for r in rows], style, label=label)
        ax.set_yscale("log")
        ax.set_xlabel("joints")
        ax.set_ylabel("ns per configuration (all joint origins)")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
