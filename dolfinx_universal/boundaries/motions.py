"""Rigid motions of a curve or surface: :class:`RigidMotion`."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from dolfinx_universal.boundaries.base import Boundary, native
from dolfinx_universal.boundaries.numerics import EPS, rotate, rotation_matrix, vector
from dolfinx_universal.core.arrays import Bool, Float, as_points

__all__ = ["RigidMotion"]


class _PlaneRotation:
    """The rotation of the plane by ``angle`` radians (counter-clockwise)."""

    def __init__(self, angle: float, rotation: object = None) -> None:
        if rotation is not None:
            raise ValueError("rotation is for surfaces (3D): give a planar motion's angle")
        self.cs = np.cos(angle), np.sin(angle)
        c, s = self.cs
        self.matrix = np.array([[c, -s], [s, c]])

    def forward(self, v: Float) -> Float:
        """Vectors ``(..., 2)`` rotated."""
        return rotate(v, *self.cs)

    def inverse(self, v: Float) -> Float:
        """Vectors ``(..., 2)`` rotated back."""
        return rotate(v, self.cs[0], -self.cs[1])

    @staticmethod
    def vector(v: npt.ArrayLike, name: str) -> Float:
        """A centre or translation: two finite numbers."""
        return vector(v, name, 2)


class _SpaceRotation:
    """A rotation of space: ``rotation`` (see :func:`rotation_matrix`), or by ``angle``
    radians about the z axis when ``rotation`` is None."""

    def __init__(self, angle: float, rotation: object = None) -> None:
        if rotation is not None and angle != 0:
            raise ValueError("give either angle (about the z axis) or rotation, not both")
        self.matrix = rotation_matrix(
            rotation if rotation is not None else ((0.0, 0.0, 1.0), angle)
        )

    def forward(self, v: Float) -> Float:
        """Vectors ``(..., 3)`` rotated."""
        return v @ self.matrix.T

    def inverse(self, v: Float) -> Float:
        """Vectors ``(..., 3)`` rotated back."""
        return v @ self.matrix

    @staticmethod
    def vector(v: npt.ArrayLike, name: str) -> Float:
        """A centre or translation: three finite numbers; two zeros (the planar default of
        the arguments) are the origin."""
        a = np.asarray(v, dtype=np.float64).reshape(-1)
        if a.shape == (2,) and not a.any():
            return np.zeros(3)
        return vector(v, name, 3)


_ROTATIONS: dict[int, type[_PlaneRotation] | type[_SpaceRotation]] = {
    2: _PlaneRotation,
    3: _SpaceRotation,
}
"""The rotation of a motion of a curve (2) or surface (3), by the dimension of the space."""


class RigidMotion(Boundary):
    """``base`` rotated about ``center``, then translated by ``translation``.

    ``y -> center + R (y - center) + translation``; everything is delegated to ``base``
    through the inverse motion (normals and tangents rotated). In 2D ``R`` is the rotation by
    ``angle``; for a surface (``base.gdim == 3``) it is ``rotation``, or the rotation by
    ``angle`` about the z axis when ``rotation`` is None.

    Parameters
    ----------
    base
        The boundary (or surface) in its reference position.
    angle
        Rotation in radians (counter-clockwise; about the z axis in 3D).
    center
        Centre of the rotation ``(gdim,)``; the default (zeros) is the origin in 3D too.
    translation
        Translation ``(gdim,)`` applied after the rotation; the default is no translation.
    rotation
        3D only (then ``angle`` must be 0): a rotation matrix ``(3, 3)``, a rotation vector
        ``(3,)`` (axis times angle) or a pair ``(axis, angle)``.
    """

    def __init__(
        self,
        base: Boundary,
        angle: float = 0.0,
        center: npt.ArrayLike = (0.0, 0.0),
        translation: npt.ArrayLike = (0.0, 0.0),
        *,
        rotation: object = None,
    ) -> None:
        self.base = base
        self.gdim = int(getattr(base, "gdim", 2))
        self.angle = float(angle)
        self._rotation = _ROTATIONS[self.gdim](self.angle, rotation)
        self.rotation = self._rotation.matrix
        """The rotation matrix ``R`` ``(gdim, gdim)``."""
        self.center = self._rotation.vector(center, "center")
        self.translation = self._rotation.vector(translation, "translation")

    def moved(
        self,
        angle: float = 0.0,
        translation: npt.ArrayLike = (0.0, 0.0),
        *,
        rotation: object = None,
    ) -> RigidMotion:
        """The same base and centre under another motion (absolute, not composed)."""
        return RigidMotion(self.base, angle, self.center, translation, rotation=rotation)

    def _to_base(self, x: npt.ArrayLike) -> Float:
        x = as_points(x, dim=self.gdim) - self.center - self.translation
        return self.center + self._rotation.inverse(x)

    def _from_base(self, y: Float) -> Float:
        return self.center + self._rotation.forward(y - self.center) + self.translation

    def _turn(self, v: Float) -> Float:
        """Vectors ``(n, gdim)`` (or ``(n, k, gdim)``) rotated by the motion."""
        return self._rotation.forward(v)

    def sign(self, x: npt.ArrayLike) -> Float:
        return self.base.sign(self._to_base(x))

    def closest_point(self, x: npt.ArrayLike) -> Float:
        return self._from_base(self.base.closest_point(self._to_base(x)))

    def project(self, x: npt.ArrayLike) -> tuple[Float, Float]:
        phi, y = self.base.project(self._to_base(x))
        return phi, self._from_base(y)

    def project_normal(self, x: npt.ArrayLike) -> tuple[Float, Float, Float]:
        if not native(self, RigidMotion, "project", "normal"):
            return Boundary.project_normal(self, x)
        phi, y, n = self.base.project_normal(self._to_base(x))
        return phi, self._from_base(y), self._turn(n)

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        if not native(self, RigidMotion, "closest_point", "normal"):
            return Boundary.closest_normal(self, x)
        y, n = self.base.closest_normal(self._to_base(x))
        return self._from_base(y), self._turn(n)

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        if not native(self, RigidMotion, "closest_point", "normal", "closest_normal"):
            return Boundary.onto_gamma(self, x)
        y, n = self.base.onto_gamma(self._to_base(x))
        return self._from_base(y), self._turn(n)

    def normal(self, y: npt.ArrayLike) -> Float:
        return self._turn(self.base.normal(self._to_base(y)))

    def tangent(self, y: npt.ArrayLike) -> Float:
        return self._turn(self.base.tangent(self._to_base(y)))

    def tangent_basis(self, y: npt.ArrayLike) -> Float:
        return self._turn(self.base.tangent_basis(self._to_base(y)))

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        return self.base.near(self._to_base(x), distance)

    def lower_bound(self, x: Float) -> Float:
        return self.base.lower_bound(self._to_base(x))

    def bounding_box(self) -> Float:
        box = np.asarray(self.base.bounding_box(), dtype=np.float64)
        d = self.gdim
        corners = np.array(np.meshgrid(*[[0, 1]] * d, indexing="ij")).reshape(d, -1)
        c = self._from_base(box[corners.T, np.arange(d)])  # the box's 2^d corners
        pad = 4 * EPS * np.abs(c).max()
        return np.array([c.min(axis=0) - pad, c.max(axis=0) + pad])

    def sample(self, n: int) -> Float:
        return self._from_base(self.base.sample(n))

    def min_radius_of_curvature(self) -> float:
        return self.base.min_radius_of_curvature()

    @property
    def euler_characteristic(self) -> int:
        """Euler characteristic of the base surface (3D)."""
        return int(self.base.euler_characteristic)  # type: ignore[attr-defined]

    @property
    def num_components(self) -> int:
        """Number of connected components of the base surface (3D)."""
        return int(self.base.num_components)  # type: ignore[attr-defined]

    def length(self) -> float:
        return self.base.length()

    def measure(self) -> float:
        return self.base.measure()

    def loops(self, spacing: float) -> list[Float]:
        return [self._from_base(q) for q in self.base.loops(spacing)]

    def loops_normals(self, spacing: float) -> tuple[list[Float], list[Float]]:
        loops, normals = self.base.loops_normals(spacing)
        return [self._from_base(q) for q in loops], [self._turn(n) for n in normals]
