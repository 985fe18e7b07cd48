"""Rigid motions of the plane for the forces on moving bodies: one rotation, scalar torques."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["ROTATIONS", "moments", "rotation", "torque"]

ROTATIONS = 1
"""Independent rotations: about ``e_z``."""


def rotation(k: int, y: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``e_z x x`` at points ``y (3, n)``, ``(2, n)`` (``k = 0``, the only rotation)."""
    return np.vstack([-y[1], y[0]])


def moments(traction: Callable[[str], Any], x: Any) -> list[Callable[[str], Any]]:
    """The moment ``x x t`` of the traction ``t = traction(side)`` about the origin as UFL
    integrands of one side: the scalar ``x_0 t_1 - x_1 t_0``."""

    def moment(side: str) -> Any:
        t, y = traction(side), x(side)
        return y[0] * t[1] - y[1] * t[0]

    return [moment]


def torque(t: npt.NDArray[np.float64]) -> float:
    """The torque from its components ``(1,)``: a float."""
    return float(t[0])
