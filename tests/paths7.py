"""Smooth random joint trajectories of the 7-joint arms, shared by tests/test_redundant.py (the
numpy search) and tests/test_kernels7.py (the search on the C kernels)."""

import numpy as np


def trajectory(name, n, rng):
    """A smooth random joint trajectory (three harmonics per joint) inside the limits and away
    from the sets where the branch labels swap (there two branches meet and "the generating
    branch" is not defined): iiwa |q2|, |q4|, |q6| >= 0.35 with fixed signs; Panda q2 of fixed
    sign away from 0, q4 on one side of the elbow's stretch, q5 away from +-pi/2."""
    if name.startswith("iiwa"):
        box = np.array([[-2.5, 2.5], [0.35, 1.8], [-2.5, 2.5], [0.35, 1.8], [-2.5, 2.5], [0.35, 1.8],
                        [-2.5, 2.5]])
        box[[1, 3, 5]] *= rng.choice([-1, 1], 3)[:, None]
    else:
        box = np.array([[-2.5, 2.5], [0.25, 1.6], [-2.5, 2.5], [-2.6, -1.0], [-1.2, 1.2], [0.3, 3.4],
                        [-2.5, 2.5]])
        box[1] *= rng.choice([-1, 1])
    box = np.sort(box, axis=1)
    t = np.arange(n)[:, None] / n
    mid, half = box.mean(1), 0.5 * (box[:, 1] - box[:, 0])
    c = mid + rng.uniform(-0.3, 0.3, 7) * half
    amp = rng.uniform(0.15, 0.35, (3, 7)) * half
    ph = rng.uniform(0, 2 * np.pi, (3, 7))
    q = c + sum(amp[k] * np.sin(2 * np.pi * (k + 1) * t + ph[k]) / (k + 1) for k in range(3))
    assert np.all((q > box[:, 0]) & (q < box[:, 1]))
    return q


def follow(nearest, poses, q0):
    """A path of poses solved by ``nearest(pose, seed)`` with each pose seeded with the previous
    answer (the first with q0); every pose must have an answer. Returns the answers (n, 7) and
    their branch ids (n,)."""
    n = len(poses)
    out, branch, cur = np.empty((n, 7)), np.empty(n, dtype=int), q0
    for i in range(n):
        r = nearest(poses[i], cur)
        assert r.found, i
        out[i], branch[i], cur = r.q, r.branch, r.q
    return out, branch


def assert_continuous(q, out, limits):
    """The answers ``out`` of the path ``q`` lie inside the limits and no step of theirs exceeds
    3 x the trajectory's own step (largest joint move)."""
    assert np.all((out >= limits[:, 0] - 1e-12) & (out <= limits[:, 1] + 1e-12))
    own = np.abs(np.diff(q, axis=0)).max(axis=1)
    step = np.abs(np.diff(out, axis=0)).max(axis=1)
    assert np.all(step <= 3.0 * own), float((step / own).max())
