"""The fast path of derive.kinematics.pose.as_pose_batch for one pose or a few (Python floats instead of
array code) and of derive.algebra.dualquat.check_unit for one, against the array code run on the same
poses in a batch larger than FEW_POSES: the same numbers bit for bit, the same errors with the same
messages."""

import numpy as np
import pytest

from derive.algebra import dualquat as dq
from derive.errors import InputError
from derive.kinematics.pose import FEW_POSES, as_pose_batch


def _array_code(x, rows=None):
    """as_pose_batch of one pose x (rows None) or of a batch x of ``rows`` poses, run by the array
    code: x repeated to a batch larger than FEW_POSES."""
    if rows is None:
        return as_pose_batch(np.stack([x] * (FEW_POSES + 1)))[0][:1]
    return as_pose_batch(np.concatenate([x] * (FEW_POSES + 1)))[0][:rows]


def _outcome(f, x):
    try:
        return "ok", f(x)
    except InputError as exc:
        return "error", str(exc)


def _same(one, batch):
    assert one[0] == batch[0], (one, batch)
    if one[0] == "error":
        assert one[1] == batch[1]
    else:
        assert one[1].tobytes() == batch[1].tobytes()     # bit for bit, signs of zeros included


def _poses(rng, n):
    """Unit dual quaternions of random rigid transforms, some scaled or bent slightly off unit
    (inside and outside the 1e-6 tolerance), some with zeros and negative zeros."""
    out = []
    for i in range(n):
        r = rng.standard_normal(4)
        r /= np.linalg.norm(r)
        t = rng.standard_normal(3) * 10.0 ** rng.integers(-3, 3)
        a = dq.from_rt(r, t)
        kind = i % 6
        if kind == 1:
            a = a * (1 + rng.choice([3e-7, -8e-7, 2e-6]))
        elif kind == 2:
            a[4:] += rng.choice([1e-7, 5e-6]) * a[:4]
        elif kind == 3:
            a[[1, 2, 5, 6]] = [0.0, -0.0, -0.0, 0.0]
            a[:4] /= np.linalg.norm(a[:4])
        elif kind == 4:
            a = -a
        out.append(a)
    return out


def test_one_dual_quaternion_is_the_batch_bit_for_bit():
    rng = np.random.default_rng(7)
    for a in _poses(rng, 600) + [np.array([1.0, 0, 0, 0, 0, 0, 0, 0]), np.array([-0.0, 1, 0, 0, -0.0, 0, 0, 0])]:
        one = _outcome(lambda x: as_pose_batch(x)[0], a)
        _same(one, _outcome(_array_code, a))
        _same(_outcome(dq.check_unit, a), _outcome(lambda x: dq.check_unit(np.stack([x, x]))[0], a))
        _same(_outcome(dq.check_unit, a[None]), _outcome(lambda x: dq.check_unit(np.stack([x, x]))[:1], a))


def test_one_matrix_is_the_batch_bit_for_bit():
    rng = np.random.default_rng(8)
    mats = []
    for a in _poses(rng, 300):
        try:
            m = dq.to_matrix(a)
        except InputError:
            continue
        mats.append(m)
        for k in range(4):       # each of Shepperd's four pivots: 180-degree turns about x, y, z
            if k:
                f = np.eye(4)
                f[:3, :3] = np.diag([1.0 if j == k - 1 else -1.0 for j in range(3)])
                mats.append(m @ f if rng.random() < 0.5 else f.copy())
    bent = mats[0].copy()
    bent[0, 1] += 2e-6
    mirrored = mats[1].copy()
    mirrored[:3, 0] *= -1.0
    bottom = mats[2].copy()
    bottom[3, 0] = 1e-8
    for m in mats + [bent, mirrored, bottom]:
        _same(_outcome(lambda x: as_pose_batch(x)[0], m),
              _outcome(_array_code, m))
        _same(_outcome(lambda x: as_pose_batch(x)[0], m[:3]),
              _outcome(_array_code, m[:3]))
    assert as_pose_batch(mats[0])[1] is True and as_pose_batch(mats[0][:3])[1] is True
    for n in (1, 2, 5, FEW_POSES):        # a few matrices in one call, a bad one among them now and then
        for _ in range(20):
            bad = bool(rng.random() < 0.1)
            batch = np.stack([mats[i] for i in rng.integers(0, len(mats), n - bad)] + [bent] * bad)
            one = _outcome(lambda x: as_pose_batch(x)[0], batch)
            _same(one, _outcome(lambda x: _array_code(x, len(x)), batch))
            _same(_outcome(lambda x: as_pose_batch(x)[0], batch[:, :3]),
                  _outcome(lambda x: _array_code(x, len(x)), batch[:, :3]))
            assert one[0] == ("error" if bad else "ok")
            if not bad:
                assert as_pose_batch(batch)[1] is False


def test_a_few_dual_quaternions_are_the_batch_bit_for_bit():
    rng = np.random.default_rng(9)
    poses = _poses(rng, 200)
    for n in (1, 2, 5, FEW_POSES):
        for _ in range(30):
            batch = np.stack([poses[i] for i in rng.integers(0, len(poses), n)])
            one = _outcome(lambda x: as_pose_batch(x)[0], batch)
            _same(one, _outcome(lambda x: _array_code(x, len(x)), batch))
            if n == 1 and one[0] == "ok":
                assert as_pose_batch(batch)[1] is False and as_pose_batch(batch[0])[1] is True


@pytest.mark.parametrize("bad, message", [
    (np.array([np.nan, 0, 0, 0, 0, 0, 0, 0]), "pose: contains NaN at index (0,)"),
    (np.array([1.0, 0, 0, 0, 0, np.inf, 0, 0]), "pose: contains inf at index (5,)"),
    (np.array([2.0, 0, 0, 0, 0, 0, 0, 0]), "pose: not a unit dual quaternion (| |real| - 1 | = 1 > 1e-06)"),
    (np.array([1.0, 0, 0, 0, 1e300, 1e300, 0, 0]), "pose: not a unit dual quaternion (the squares of its dual part overflow)"),
    (np.diag([1.0, 1.0, -1.0, 1.0]), "pose: the 3x3 block is not a rotation matrix (max |R^T R - I| = 0)"),
    (np.full((4, 4), np.inf), "pose: contains inf at index (0, 0)"),
])
def test_one_pose_errors(bad, message):
    with pytest.raises(InputError) as exc:
        as_pose_batch(bad)
    assert str(exc.value) == message
