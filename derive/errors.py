"""The project's exceptions and the input checks that raise them.

Every bad input (wrong shape, NaN or inf, unknown robot, malformed robot file,
non-unit pose) raises :class:`DeriveError` or one of its subclasses, with a
message that names the problem. Nothing returns NaN silently.
"""

from __future__ import annotations

import numpy as np


class DeriveError(Exception):
    """Base class of every error raised by dq-derive."""


class InputError(DeriveError, ValueError):
    """An argument has the wrong shape, is not finite, or is out of range."""


class UnknownRobotError(DeriveError, LookupError):
    """A robot name is neither in the library nor a path to a description file."""


class RobotFileError(DeriveError):
    """A robot description file is malformed or inconsistent."""


def as_finite_array(value, name: str, last_dim: int | None = None,
                    ndim_min: int = 1) -> np.ndarray:
    """Return ``value`` as a float64 array after checking its shape and values.

    ``last_dim`` is the required size of the last axis (4 for a quaternion, 8
    for a dual quaternion, 3 for a vector); ``None`` accepts any size.
    """
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be read as an array of numbers ({exc})") from None
    if arr.ndim < ndim_min:
        raise InputError(f"{name}: expected at least {ndim_min} dimension(s), got shape {arr.shape}")
    if last_dim is not None and arr.shape[-1] != last_dim:
        raise InputError(f"{name}: expected last dimension {last_dim}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        kind = "NaN" if np.isnan(arr[tuple(bad)]) else "inf"
        raise InputError(f"{name}: contains {kind} at index {tuple(int(i) for i in bad)}")
    return arr
