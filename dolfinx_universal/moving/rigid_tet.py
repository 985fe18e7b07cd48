"""Rigid motions of space for the forces on moving bodies: three rotations, vector torques."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt
import ufl

__all__ = ["ROTATIONS", "moments", "rotation", "torque"]

ROTATIONS = 3
"""Independent rotations: about ``e_x``, ``e_y``, ``e_z``."""


def rotation(k: int, y: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``e_k x x`` at points ``y (3, n)``, ``(3, n)``."""
    e = np.zeros((3, 1))
    e[k] = 1.0
    return np.cross(e.T, y.T).T


def moments(traction: Callable[[str], Any], x: Any) -> list[Callable[[str], Any]]:
    """The moment ``x x t`` of the traction ``t = traction(side)`` about the origin as UFL
    integrands of one side: its three components."""

    def moment(side: str) -> Any:
        t, y = traction(side), x(side)
        return ufl.cross(y, t)

    def component(i: int) -> Callable[[str], Any]:
        return lambda side: moment(side)[i]

    return [component(i) for i in range(ROTATIONS)]


def torque(t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """The torque from its components ``(3,)``: the vector."""
    return t
