"""Fault suite, fuzzing part (issue 33, item 7; docs/reliability.md): the robot loader and the
pose contract of the kernels take arbitrary input and end with the right answer or a
``DeriveError``, never another exception and never a hang.

* Robot files: hypothesis edits the UR5's description (any field of a joint replaced by a
  number, an expression, a string, a list, None; keys dropped or added; the text cut short or
  garbled) and the loader reads the file. Where it accepts one, the robot is usable: its FK by
  the dual-quaternion product equals the plain 4x4 matrix product (two independent paths) to
  1e-9 relative to its size.
* Poses: arrays of any shape (up to 4 axes), dtype (float, int, bool, complex, object, str) and
  values (NaN, inf, huge, tiny, non-unit) go to ``k.ik`` of the C (extension) and numpy kernels;
  an accepted pose gives solutions that reproduce it.

The time bound of each example is hypothesis' deadline (none in the CI profile, so a hang would
show as the test's own time-out in CI's 90 minutes; each example here takes milliseconds).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import derive
from derive import DeriveError, reference
from derive.model.robot import load_robot

UR5_TEXT = Path(load_robot("ur5").path).read_text(encoding="utf-8")
UR5 = yaml.safe_load(UR5_TEXT)
FIELDS = ("d", "a", "alpha", "theta", "offset", "limits", "name", "type")

# values a field may be given: numbers of every size, expressions (some bounded, some not),
# strings, lists, nothing
numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(min_value=-10**400, max_value=10**400))
expressions = st.one_of(
    st.sampled_from(["pi/2", "-pi", "2*pi", "d1", "a2*2", "10**10**10", "10.0**400", "2**10000", "(-1)**0.5",
                     "1e308*10", "sqrt(2)/2", "__import__('os')", "pi/", "()", "a2 a3", "nan", "inf", "-inf",
                     "1/0", "0**-1", "pi**pi**pi", "d1" * 200]),
    st.text(alphabet="0123456789+-*/()pi.e ad", max_size=30))
values = st.one_of(numbers, expressions, st.none(), st.booleans(),
                   st.lists(st.one_of(numbers, expressions), max_size=3),
                   st.dictionaries(st.sampled_from(["x", "y", "lower"]), numbers, max_size=2))


def _fk_paths_agree(robot) -> None:
    """An accepted robot is usable: FK by dual quaternions equals the 4x4 matrix product."""
    q = np.linspace(-0.7, 0.9, robot.dof)
    Q = reference.fk(robot, q)
    T = reference.fk_matrix(robot, q)
    M = derive.dualquat.to_matrix(Q)
    scale = 1.0 + float(np.max(np.abs(T[:3, 3])))
    assert np.all(np.isfinite(Q))
    assert np.max(np.abs(M - T)) <= 1e-9 * scale


def _load_or_refuse(path) -> None:
    try:
        robot = load_robot(path)
    except DeriveError as exc:
        assert str(exc)                              # a message that names the problem
        return
    _fk_paths_agree(robot)


@settings(max_examples=80, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=st.lists(st.tuples(st.integers(0, 5), st.sampled_from(FIELDS), values), min_size=1, max_size=3))
def test_edited_description_loads_or_is_a_derive_error(tmp_path, edits):
    data = yaml.safe_load(UR5_TEXT)
    for joint, field, value in edits:
        data["joints"][joint][field] = value
    path = tmp_path / "fuzz.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    _load_or_refuse(path)


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(top=st.dictionaries(st.sampled_from(["name", "convention", "units", "parameters", "joints", "end",
                                            "base", "tool", "nominal", "extra"]), values, max_size=4),
       drop=st.sets(st.sampled_from(["name", "convention", "units", "parameters", "joints"]), max_size=2))
def test_top_level_keys_replaced_or_dropped(tmp_path, top, drop):
    data = yaml.safe_load(UR5_TEXT)
    data.update(top)
    for key in drop:
        data.pop(key, None)
    path = tmp_path / "fuzz.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    _load_or_refuse(path)


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, len(UR5_TEXT)), garbage=st.text(max_size=20), at=st.integers(0, len(UR5_TEXT)))
def test_cut_or_garbled_file(tmp_path, cut, garbage, at):
    text = UR5_TEXT[:cut]
    text = text[:at] + garbage + text[at:]
    path = tmp_path / "fuzz.yaml"
    path.write_text(text, encoding="utf-8")
    _load_or_refuse(path)


def test_the_fuzzed_loader_accepts_the_unedited_file(tmp_path):
    """The check above can pass by refusing everything: the untouched file must load and agree."""
    path = tmp_path / "fuzz.yaml"
    path.write_text(UR5_TEXT, encoding="utf-8")
    robot = load_robot(path)
    assert robot.dof == 6
    _fk_paths_agree(robot)


# --------------------------------------------------------------------------- #
# The pose contract
# --------------------------------------------------------------------------- #
@pytest.fixture(scope="module", params=["c", "numpy"])
def kern(request):
    return derive.kernels("ur5", request.param)


shapes = st.lists(st.integers(0, 5), min_size=0, max_size=4).map(tuple) | st.sampled_from(
    [(8,), (3, 8), (4, 4), (2, 4, 4), (3, 4), (2, 3, 4), (2, 2, 4, 4), (1, 8), (0, 8), (8, 1)])
fill = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, 1.0, 1e300, 1e-300, -1.0]))
dtypes = st.sampled_from([np.float64, np.float32, np.int64, np.bool_, np.complex128, object, str])


@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(shape=shapes, value=fill, dtype=dtypes, noise=st.booleans())
def test_any_pose_array_solves_or_is_a_derive_error(kern, shape, value, dtype, noise):
    rng = np.random.default_rng(abs(hash((shape, str(dtype)))) % 2**32)
    base = np.full(shape, value, dtype=float)
    if noise and base.size:
        base = base + rng.normal(size=shape)
    with np.errstate(invalid="ignore", over="ignore"):
        arr = base.astype(dtype) if dtype is not str else base.astype(str)
    try:
        sols, counts = kern.ik(arr)
    except DeriveError as exc:
        assert str(exc)
        return                    # refused, with a message: the contract holds
    # accepted: as many solutions as counted, each finite, and NaN past the count
    counts = np.atleast_1d(np.asarray(counts)).reshape(-1)
    if counts.size == 0:                          # an empty batch: nothing to solve
        assert np.asarray(sols).size == 0
        return
    rows = np.asarray(sols, dtype=float).reshape(len(counts), -1, 6)
    filled = np.arange(rows.shape[1])[None, :] < counts[:, None]
    assert np.all(np.isfinite(rows[filled])) and np.all(np.isnan(rows[~filled]))


def test_valid_poses_pass_the_pose_contract(kern):
    """The contract test above must not pass by refusing everything: real poses (dual
    quaternions, 4x4 and 3x4 matrices, batches and single poses) are accepted, give the same
    counts in every form, and every solution reproduces its pose (plain 4x4 matrices)."""
    rng = np.random.default_rng(7)
    q = rng.uniform(-math.pi, math.pi, (5, 6))
    P = reference.fk("ur5", q)
    T = np.stack([reference.fk_matrix("ur5", qi) for qi in q])
    _, want = kern.ik(P)
    assert np.all(np.asarray(want) >= 1)
    for pose, n in ((P, 5), (T, 5), (T[:, :3, :], 5), (P[0], 1), (T[0], 1)):
        sols, counts = kern.ik(pose)
        counts = np.atleast_1d(counts)
        assert np.array_equal(counts, np.asarray(want)[:n])
        rows = np.asarray(sols).reshape(n, -1, 6)
        for i in range(n):
            for sol in rows[i, :counts[i]]:
                assert np.max(np.abs(reference.fk_matrix("ur5", sol) - T[i])) < 1e-9
