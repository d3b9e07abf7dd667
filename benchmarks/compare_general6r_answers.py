"""Did a change to the general 6R numpy reference or numpy kernels change their answers? Dump one
tree's answers, dump another's, compare.

    .venv/bin/python benchmarks/compare_general6r_answers.py dump OUT.npz [--which ref|numpy]
        [--arms crx10ia,xarm6,jaco2-6dof,general-6r] [--poses 2000]
    PYTHONPATH=/path/to/other/tree .venv/bin/python benchmarks/compare_general6r_answers.py dump B.npz
    .venv/bin/python benchmarks/compare_general6r_answers.py compare A.npz B.npz

``dump`` solves, per arm, ``--poses`` random configurations within the limits (seed 0) and every
axis-aligned configuration of ``bench_general6r_axis_aligned.configurations`` (not for
general-6r) with the numpy reference (``general6r.solve``) or the numpy kernels (``ik_general``),
and stores solutions, counts, singular and degenerate flags. ``compare`` prints per set whether
counts and flags are equal, the largest joint difference (mod 2 pi) where the NaN patterns agree,
and the poses that differ at all: how many of them the new side flags degenerate, and how many of
the first side's solutions are missing (within 1e-4 rad) at a pose the new side does not flag.
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import numpy as np

ARMS = "crx10ia,xarm6,jaco2-6dof,general-6r"


def _axis_aligned():
    path = Path(__file__).resolve().parent / "bench_general6r_axis_aligned.py"
    spec = importlib.util.spec_from_file_location("bench_general6r_axis_aligned", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def dump(out, which="ref", arms=ARMS, n=2000):
    import derive
    from derive import reference
    from derive.ik import general6r

    aa = _axis_aligned()
    data = {}
    for arm in arms.split(","):
        r = derive.load_robot(arm)
        rng = np.random.default_rng(0)
        lo, hi = np.maximum(r.limits[:, 0], -np.pi), np.minimum(r.limits[:, 1], np.pi)
        sets = {"rand": reference.fk(r, rng.uniform(lo, hi, (n, 6)))}
        if arm != "general-6r":
            sets["axis"] = reference.fk(r, aa.configurations(r))
        for name, poses in sets.items():
            if which == "ref":
                s = general6r.solve(r, poses)
                out_ = (s.q, s.counts, s.singular, s.degenerate)
            else:
                out_ = derive.kernels(r, "numpy")._mod.ik_general(poses)
            for key, v in zip("qcsd", out_):
                data[f"{arm}/{name}/{key}"] = np.asarray(v)
            print(f"{arm} {name}: {len(poses)} poses", flush=True)
    np.savez(out, **data)


def _contains(sols, s, tol):
    return any(np.max(np.abs(np.angle(np.exp(1j * (x - s))))) < tol for x in sols)


def compare(a_path, b_path) -> bool:
    a, b = np.load(a_path), np.load(b_path)
    same_all = True
    for key in sorted({k.rsplit("/", 1)[0] for k in a.files}):
        qa, qb, ca, cb = a[key + "/q"], b[key + "/q"], a[key + "/c"], b[key + "/c"]
        sa, sb, da, db = a[key + "/s"], b[key + "/s"], a[key + "/d"], b[key + "/d"]
        fin = np.isfinite(qa)
        nan_same = np.array_equal(fin, np.isfinite(qb))
        diff = float(np.abs(np.angle(np.exp(1j * (qa[fin] - qb[fin])))).max()) if nan_same and fin.any() else np.nan
        good = np.array_equal(ca, cb) and np.array_equal(sa, sb) and np.array_equal(da, db) and nan_same and diff <= 1e-12
        same_all &= good
        poses = [i for i in range(len(ca)) if ca[i] != cb[i] or not np.array_equal(sa[i], sb[i])
                 or not all(_contains(qb[i, :cb[i]], s, 1e-9) for s in qa[i, :ca[i]])]
        lost = [i for i in range(len(ca)) if not db[i] and not all(_contains(qb[i, :cb[i]], s, 1e-4) for s in qa[i, :ca[i]])]
        print(f"{key:20s} {len(ca)} poses: counts {np.array_equal(ca, cb)}, singular {np.array_equal(sa, sb)}, "
              f"degenerate {np.array_equal(da, db)}, max |dq| {diff:.1e}, bitwise "
              f"{np.array_equal(np.nan_to_num(qa), np.nan_to_num(qb))}; poses differing {len(poses)} "
              f"(flagged {sum(bool(db[i]) for i in poses)}), solutions missing at unflagged poses: {len(lost)} poses"
              f" -> {'same' if good else 'DIFFERENT'}")
    print("all the same (counts, flags, solutions to 1e-12)" if same_all else "differences above")
    return same_all


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump")
    d.add_argument("out")
    d.add_argument("--which", choices=["ref", "numpy"], default="ref")
    d.add_argument("--arms", default=ARMS)
    d.add_argument("--poses", type=int, default=2000)
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args(argv)
    if args.cmd == "dump":
        dump(args.out, args.which, args.arms, args.poses)
    else:
        compare(args.a, args.b)


if __name__ == "__main__":
    main()
