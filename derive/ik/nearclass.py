"""Near-class arms: a description a little off a class with a closed form (a URDF's printed
constants such as 1.570796325, decimal DH such as ``alpha: 1.5708``, a calibrated arm, axes
that miss by fractions of a millimetre) keeps the closed form of its *nominal* robot, an exact
member of the class, and every candidate is polished by Newton steps on the arm's own FK.

This module holds the interface shared by the numpy reference (:mod:`derive.ik`) and the
emitted kernels (:mod:`derive.codegen`): :class:`Nominal`, the exact robot and the constant
relation between the two chains,

    FK_robot(q) ~= B FK_nominal(signs * q + offsets) T,

with B and T unit dual quaternions (scalar-first, [real | dual]) and the relation's largest
mismatch on sample configurations in ``deviation``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.model.robot import Robot

__all__ = ["Nominal"]


@dataclass(frozen=True)
class Nominal:
    """The nominal robot of a near-class arm and the relation to it.

    robot: an exact robot of a class with a closed form, with the arm's number of joints.
    base, tool: (8,) unit dual quaternions B and T of FK_robot(q) ~= B FK_nominal(s q + o) T.
    signs: (dof,) +1 or -1 per joint variable (s); offsets: (dof,) radians (o).
    deviation: the largest mismatch of that relation (metres or radians) on sample
    configurations; the Newton polish removes it.
    how: one line saying how the nominal robot was found (for messages).
    """

    robot: Robot
    base: np.ndarray
    tool: np.ndarray
    signs: np.ndarray
    offsets: np.ndarray
    deviation: float
    how: str
