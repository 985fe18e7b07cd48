"""The messages of the Gamma_h topology checks of triangles and tetrahedra, in one place."""

from __future__ import annotations

from typing import NamedTuple

from dolfinx_universal.core.arrays import Float
from dolfinx_universal.core.collective import where

__all__ = ["TOPOLOGY_MESSAGES", "TopologyMessages"]


class TopologyMessages(NamedTuple):
    """The messages of the Gamma_h topology checks of both dimensions, in one place:
    :func:`~dolfinx_universal.conforming.checks_tri.gamma_h_topology` (triangles: loops of
    positive edges following curves) and
    :func:`~dolfinx_universal.conforming.checks_tet.surface_topology` (tetrahedra: closed
    pieces of positive faces following surfaces). Each returns a :class:`Problem` template
    (``{where}`` and ``{count}`` filled in by :func:`raise_collective`)."""

    part: str
    """A connected part of Gamma: "curve" or "surface"."""
    facet: str
    """"edge" or "face"."""
    loop: str
    """A closed part of Gamma_h: "loop" or "piece"."""
    cells: str
    """"triangles" or "tetrahedra"."""

    def empty(self, num_parts: int) -> str:
        return (
            f"Gamma_h is empty: no positive {self.facet} follows any of the {num_parts} "
            f"{self.part}s of the boundary near {{where}}; the background is too coarse for "
            "the domain there; refine near those points"
        )

    def joined(self, pairs: list[tuple[int, int]]) -> str:
        """Parts ``(i, j)`` of Gamma followed by one closed part of Gamma_h."""
        names = ", ".join(f"{i} and {j}" for i, j in pairs[:3])
        return (
            f"Gamma_h joins different {self.part}s of the boundary ({self.part}s {names}) "
            "near {where}: the gap between them is not resolved by the background; refine "
            "to below the gap there"
        )

    def lost(self, k: int, first: Float) -> str:
        """Part ``k`` of Gamma followed by nothing (``first``: one of its samples)."""
        return (
            f"{self.part} {k} of the boundary (near {where(first)}) is lost: no {self.loop} "
            "of Gamma_h follows it, so the mesh would ignore that part of the boundary (a "
            f"body or feature smaller than the background's {self.cells}); refine the "
            "background near it (places: {where})"
        )

    def split(self, k: int, n: int) -> str:
        """Part ``k`` of Gamma followed by ``n`` closed parts of Gamma_h."""
        return (
            f"{self.part} {k} of the boundary is split into {n} {self.loop}s of Gamma_h: a "
            "neck or thin part of the domain (or a gap) is narrower than the background's "
            f"{self.cells} near {{where}}; refine the background there"
        )

    def wrong_side(self, k: int) -> str:
        return (
            f"Gamma_h around {self.part} {k} keeps the wrong side of it near {{where}}: the "
            "background is too coarse for the domain there; refine near it"
        )

    def pieces(self, pieces: int, expected: int) -> str:
        return (
            f"the kept {self.cells} form {pieces} connected pieces where the domain has "
            f"{expected}, near {{where}}: refine the background near them"
        )


TOPOLOGY_MESSAGES = {
    2: TopologyMessages("curve", "edge", "loop", "triangles"),
    3: TopologyMessages("surface", "face", "piece", "tetrahedra"),
}
"""The messages of the Gamma_h topology checks by topological dimension."""
