"""Strict input: booleans, complex numbers and strings are refused (InputError naming the
argument), on the numpy/Python paths as in the C extension; every option of refine is checked."""

import numpy as np
import pytest

from derive import reference
from derive.codegen.loader import kernels
from derive.errors import InputError, as_finite_array, finite_number, whole_number
from derive.kinematics import pose as P
from derive.refinement.solver import refine

Q = [0.1, -0.4, 0.7, 0.2, 0.5, -0.3]


@pytest.mark.parametrize("value, message", [
    (True, "q: expected a real number, got bool"),
    ([0.1, True, 0, 0, 0, 0], "q: expected a real number, got bool"),
    (np.array([1, 0, 1, 1, 0, 0], dtype=bool), "q: expected real numbers, got an array of dtype bool"),
    ([0.1, 1 + 0j, 0, 0, 0, 0], "q: expected a real number, got complex"),
    (np.array(Q, dtype=complex), "q: expected real numbers, got an array of dtype complex128"),
    ("1.0", "q: expected a real number, got str '1.0'"),
    (["1.0", "0", "0", "0", "0", "0"], "q: expected a real number, got str '1.0'"),
    ([[0.1, 0, 0, 0, 0, "0"]], "q: expected a real number, got str '0'"),
    (np.array(["1.0"] * 6), "q: expected real numbers, got an array of dtype <U3"),
    (np.array(Q, dtype=object), "q: expected real numbers, got an array of dtype object"),
])
def test_fk_refuses_bool_complex_str(value, message):
    with pytest.raises(InputError) as info:
        reference.fk("ur5", value)
    assert str(info.value).startswith(message)


def test_real_numbers_still_pass():
    """ints, numpy integers and float32 are real numbers: the same pose as the float64 input."""
    a = reference.fk("ur5", np.array(Q))
    assert np.array_equal(reference.fk("ur5", [0, 0, 0, 0, 0, 0]), reference.fk("ur5", np.zeros(6)))
    assert np.array_equal(reference.fk("ur5", np.array([1, 2, 3, 4, 5, 6], dtype=np.int32)),
                          reference.fk("ur5", [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
    assert np.allclose(reference.fk("ur5", np.array(Q, dtype=np.float32)), a, atol=1e-6)


def test_pose_inputs_refuse_complex_and_str():
    with pytest.raises(InputError, match="^pose: expected real numbers, got an array of dtype complex"):
        reference.ik("ur5", np.array(reference.fk("ur5", Q), dtype=complex))
    with pytest.raises(InputError, match="^position: expected a real number, got str"):
        P.from_position_rpy(["0.4", 0.1, 0.3], [0, 0, 0])
    with pytest.raises(InputError, match="^rpy: expected a real number, got bool"):
        P.from_position_rpy([0.4, 0.1, 0.3], [True, 0, 0])
    with pytest.raises(InputError, match="^quaternion: expected a real number, got complex"):
        P.from_position_quaternion([0.4, 0.1, 0.3], [1j, 0, 0, 1], "xyzw")


def test_as_finite_array_names_the_argument():
    with pytest.raises(InputError, match="^weights: expected a real number, got bool"):
        as_finite_array([1.0, False], "weights")
    assert as_finite_array([1, 2], "x").dtype == np.float64


def test_scalar_checks():
    assert finite_number(3, "tol", minimum=0.0, strict=True) == 3.0
    assert whole_number(np.int64(4), "max_iter", minimum=1) == 4
    for bad in (True, "1.0", 1j, None):
        with pytest.raises(InputError, match="^tol: expected a real number"):
            finite_number(bad, "tol")
    for bad in (True, 2.0, "3", None):
        with pytest.raises(InputError, match="^max_iter: expected an integer"):
            whole_number(bad, "max_iter")


def test_rpy_pose_matches_the_rotation_product():
    """R = Rz(yaw) Ry(pitch) Rx(roll), written out here with plain matrices."""
    roll, pitch, yaw = 0.3, -0.7, 1.9
    cx, sx, cy, sy, cz, sz = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rz @ ry @ rx, [0.4, 0.1, 0.3]
    pose = P.from_position_rpy([0.4, 0.1, 0.3], [roll, pitch, yaw])
    assert np.allclose(P.as_pose(m), pose, atol=1e-15) or np.allclose(P.as_pose(m), -pose, atol=1e-15)
    t, rpy = P.to_position_rpy(pose)
    assert np.allclose(t, [0.4, 0.1, 0.3], atol=1e-15) and np.allclose(rpy, [roll, pitch, yaw], atol=1e-12)


# --------------------------------------------------------------------------- #
# refine: every option checked before any solving
# --------------------------------------------------------------------------- #
POSE = reference.fk("ur5", Q)


@pytest.mark.parametrize("options, message", [
    ({"max_iter": 0}, "max_iter: must be an integer >= 1, got 0"),
    ({"max_iter": -3}, "max_iter: must be an integer >= 1, got -3"),
    ({"max_iter": 10.0}, "max_iter: expected an integer, got float 10.0"),
    ({"max_iter": True}, "max_iter: expected an integer, got bool True"),
    ({"max_iter": "50"}, "max_iter: expected an integer, got str '50'"),
    ({"tol": float("nan")}, "tol: must be finite, got nan"),
    ({"tol": float("inf")}, "tol: must be finite, got inf"),
    ({"tol": 0.0}, "tol: must be > 0, got 0"),
    ({"tol": -1e-9}, "tol: must be > 0, got -1e-09"),
    ({"tol": "1e-9"}, "tol: expected a real number, got str '1e-9'"),
    ({"tol": 1e-9 + 0j}, "tol: expected a real number, got complex"),
    ({"weights": (1.0, -1.0)}, "weights: (position, rotation), two finite numbers >= 0, not both 0; got (1, -1)"),
    ({"weights": (np.float64(-1.0), 1.0)}, "weights: (position, rotation), two finite numbers >= 0, not both 0; got (-1, 1)"),
    ({"weights": (0.0, 0.0)}, "weights: (position, rotation), two finite numbers >= 0, not both 0; got (0, 0)"),
    ({"weights": (1.0, float("nan"))}, "weights: contains NaN at index (1,)"),
    ({"weights": (1.0, True)}, "weights: expected a real number, got bool"),
    ({"weights": (1.0, 1.0, 1.0)}, "weights: expected last dimension 2"),
    ({"regularization": -0.1}, "regularization: must be >= 0, got -0.1"),
    ({"regularization": float("inf")}, "regularization: must be finite, got inf"),
    ({"regularization": False}, "regularization: expected a real number, got bool"),
    ({"starts": 0}, "starts: must be an integer >= 1, got 0"),
    ({"seed": -1}, "seed: must be an integer >= 0, got -1"),
    ({"seed": 1.5}, "seed: expected an integer, got float 1.5"),
    ({"retry_sigmas": (0.1, -0.2)}, "retry_sigmas: must be > 0, got (0.1, -0.2)"),
    ({"retry_sigmas": (0.1, float("nan"))}, "retry_sigmas: contains NaN"),
    ({"q0": [0, 0, 0, 0, 0, "0"]}, "q0: expected a real number, got str"),
    ({"q0": [0, 0, 0]}, r"q0: expected (6,) or (k, 6), got (1, 3)"),
    ({"q_ref": [0, 0, 0, 0, 0, 1j]}, "q_ref: expected a real number, got complex"),
])
def test_refine_checks_every_option(options, message):
    with pytest.raises(InputError) as info:
        refine("ur5", POSE, **options)
    assert str(info.value).startswith(message)
    assert "np.float64" not in str(info.value)


def test_refine_checks_the_pose():
    with pytest.raises(InputError, match="^pose: expected real numbers, got an array of dtype complex"):
        refine("ur5", POSE.astype(complex))


@pytest.mark.parametrize("backend", ["python", "numpy", "c"])
@pytest.mark.parametrize("value, message", [
    ([0.1, True, 0, 0, 0, 0], "Q: expected a real number, got bool"),
    ([0.1, 1j, 0, 0, 0, 0], "Q: expected a real number, got complex"),
    (["0.1"] * 6, "Q: expected a real number, got str"),
    (np.ones(6, dtype=bool), "Q: expected real numbers, got an array of dtype"),
])
def test_kernel_backends_refuse_alike(backend, value, message):
    """The Python and numpy kernels refuse what the C extension refuses, with the same message."""
    k = kernels("ur5", backend)
    with pytest.raises(InputError) as info:
        k.fk(value)
    assert str(info.value).startswith(message)
    with pytest.raises(InputError) as info:
        k.ik(np.array(POSE, dtype=complex))
    assert str(info.value).startswith("pose: expected real numbers, got an array of dtype")
