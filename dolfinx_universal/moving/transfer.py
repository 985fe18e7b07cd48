"""Carry finite element functions between two geometries of one moving mesh.

A :class:`~dolfinx_universal.moving.domain.MovingDomain` keeps its topology and dofmaps for
every step; only the geometry nodes and the active cells change. A function of a step is
its dof values with that step's nodes. :class:`NodeTransfer` gives the dof values of the
same function for other nodes (those of the next triangulation): where a cell is active
in both and its nodes did not move the values are kept; elsewhere each moved dof is the
old function evaluated at its new place, located among the old active cells around it;
a place outside the old domain (a cell that has just entered) takes the value of the
polynomial of the nearest old active cell, continued outside it: an extension of the
same order as the interpolation (Gawlik & Lew 2014 extend the solution to entering nodes
in the same way).
"""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import basix
import numpy as np
import numpy.typing as npt
from dolfinx import fem
from scipy.spatial import cKDTree

from dolfinx_universal.core.collective import Problem, raise_collective, vertex_reduce

__all__ = ["MixedTransfer", "NodeTransfer", "node_transfer"]

NEWTON_STEPS = 12
"""Newton steps of the pull-back onto a curved cell (quadratic convergence from the affine
start: 3-5 steps reach rounding for the cells of a valid mesh)."""

SAME_PLACE = 1e-13
"""Nodes closer than this times the mesh's extent count as unmoved: a dof at the same place
keeps its value (evaluating it there would give it back up to rounding)."""

NEWTON_TOLERANCE = 1e-11
"""Largest residual of a pull-back, relative to the cell's size, taken as converged (a
point far outside a curved cell may lie beyond the reach of its map's continuation)."""

INSIDE = 1e-10
"""A point whose smallest barycentric coordinate in a cell is above ``-INSIDE`` is in it."""

LAYERS = 2
"""Vertex neighbourhoods around the old boundary and the moved cells whose old cells every
rank considers for the places that its own cells do not hold (a point moves by less than
a cell between two steps of a time integrator that resolves the motion)."""

STRAIGHT = 1e-12
"""A cell whose nodes are within this times its size of the affine map's is straight: the
affine inverse is its pull-back (to well within :data:`NEWTON_TOLERANCE`)."""

NEAREST = 12
"""Old active cells (nearest centroids) tried for a point outside the old cells around it."""


def _csr(
    rows: npt.NDArray[np.int32], n: int
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """The transpose of the cell -> vertex table ``rows (m, k)``: offsets and cells."""
    flat = rows.ravel()
    order = np.argsort(flat, kind="stable")
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(flat, minlength=n), out=offsets[1:])
    return offsets, (order // rows.shape[1]).astype(np.int64)


class NodeTransfer:
    """Dof values of functions of ``V`` for other geometry nodes of the same mesh.

    Parameters
    ----------
    mesh
        The moving mesh (its topology and geometry dofmap; its nodes are not read).
    cell_vertices
        Vertices of the process-local cells ``(num_cells, tdim + 1)``.
    V
        A (blocked) Lagrange space on ``mesh``.
    """

    def __init__(self, mesh, cell_vertices: npt.NDArray[np.int32], V: fem.FunctionSpace) -> None:
        self.V = V
        self.tdim = tdim = mesh.topology.dim
        cmap = mesh.geometry.cmaps[0]
        self._geometry = basix.create_element(
            basix.ElementFamily.P,
            basix.CellType.triangle if tdim == 2 else basix.CellType.tetrahedron,
            cmap.degree,
            basix.LagrangeVariant(int(cmap.variant)),
        )
        self._gdofmap = mesh.geometry.dofmaps[0]
        self._basis = V.element.basix_element
        points = V.element.interpolation_points
        self._N = self._geometry.tabulate(0, points)[0, :, :, 0]  # (ndofs of V, nodes)
        self._linear = basix.create_element(
            basix.ElementFamily.P, self._geometry.cell_type, 1, basix.LagrangeVariant.equispaced
        ).tabulate(0, self._geometry.points)[0, :, :, 0]  # (nodes, tdim + 1)
        self._dofmap = V.dofmap.list
        self._bs = V.dofmap.index_map_bs
        self._owned = V.dofmap.index_map.size_local
        self._c2v = cell_vertices
        self._v2c = _csr(cell_vertices, int(cell_vertices.max(initial=-1)) + 1)
        imap = V.dofmap.index_map
        self._d2c = _csr(self._dofmap, imap.size_local + imap.num_ghosts)
        self._vertices = mesh.topology.index_map(0)
        self._owned_cells = mesh.topology.index_map(tdim).size_local
        self._straight_cache: dict[tuple[Any, ...], npt.NDArray[np.bool_]] = {}
        self._comm = mesh.comm
        # cells' numbers in the input mesh: the same on any number of ranks, they decide
        # between the cells holding a point on their common boundary
        ncells = len(cell_vertices)
        original = np.asarray(mesh.topology.original_cell_index, dtype=np.float64)
        self._cell_key = (
            original[:ncells] if len(original) >= ncells else np.arange(ncells, dtype=np.float64)
        )

    # -- geometry -------------------------------------------------------------------------

    def moved_cells(
        self,
        x_old: npt.NDArray[np.float64],
        active_old: npt.NDArray[np.bool_],
        x_new: npt.NDArray[np.float64],
        active_new: npt.NDArray[np.bool_],
        also: npt.NDArray[np.bool_] | None = None,
    ) -> npt.NDArray[np.int64]:
        """The cells active for ``x_new`` whose dofs need new values: a node moved (or is
        marked in ``also``), or the cell was not active for ``x_old`` (collective)."""
        scale = self._comm.allreduce(float(np.abs(x_new).max(initial=1.0)), op=MPI.MAX)
        moved = (np.abs(x_new - x_old) > SAME_PLACE * scale).any(axis=1)
        if also is not None:
            moved |= also
        cells = np.flatnonzero(active_new)
        hit = moved[self._gdofmap[cells]].any(axis=1) | ~active_old[cells]
        return cells[hit]

    def pull_back(
        self,
        points: npt.NDArray[np.float64],
        cells: npt.NDArray[np.int64],
        x: npt.NDArray[np.float64],
        straight: npt.NDArray[np.bool_] | None = None,
    ) -> npt.NDArray[np.float64]:
        """Reference coordinates of ``points (n, tdim)`` in ``cells (n,)`` of the geometry
        ``x``: the affine map's inverse, exact on straight cells; on curved cells Newton's
        method on the degree-q map from there (valid for points outside the cell too: the
        map's polynomial continued); NaN where it does not converge. ``straight``: which
        cells of ``x`` are straight (:meth:`straight_cells`; computed when not given)."""
        d = self.tdim
        vertices = x[self._gdofmap[cells, : d + 1], :d]  # (n, d + 1, d)
        if self._geometry.degree == 1 or len(points) == 0:
            return self._pull_back(points, vertices)
        if straight is None:
            straight = self.straight_cells(x)
        curved = np.flatnonzero(~straight[cells])
        return self._pull_back(points, vertices, curved, x[self._gdofmap[cells[curved]], :d])

    def _pull_back(
        self,
        points: npt.NDArray[np.float64],
        vertices: npt.NDArray[np.float64],
        curved: npt.NDArray[np.intp] | None = None,
        nodes: npt.NDArray[np.float64] | None = None,
    ) -> npt.NDArray[np.float64]:
        """:meth:`pull_back` given the cells' vertices ``(n, tdim + 1, tdim)``, which
        points are in curved cells and those cells' nodes."""
        J = np.swapaxes(vertices[:, 1:] - vertices[:, :1], 1, 2)
        X = np.einsum("nij,nj->ni", _inverse(J), points - vertices[:, 0])
        if curved is not None and nodes is not None and len(curved):
            size = np.abs(J[curved]).max(axis=(1, 2))
            X[curved] = self._newton(points[curved], nodes, X[curved], size)
        return X

    def straight_cells(self, x: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
        """Which cells of the geometry ``x`` are straight: their nodes are within
        :data:`STRAIGHT` times their size of the affine map's."""
        return self._straight(x[self._gdofmap, : self.tdim])

    def _straight_of(self, x: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
        """:meth:`straight_cells` of ``x``, kept for later calls with the same nodes (a
        step's nodes serve several transfers: every sub-space, and the steps of a BDF
        stencil): the same array memory, shape and sum of the nodes."""
        tag = (x.__array_interface__["data"][0], x.shape, float(x.sum()))
        cache = self._straight_cache
        if tag not in cache:
            while len(cache) >= 4:  # the nodes of the last few steps
                del cache[next(iter(cache))]
            cache[tag] = self.straight_cells(x)
        return cache[tag]

    def _straight(self, nodes: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
        """:meth:`straight_cells` of cells given by their nodes ``(cells, nodes, tdim)``."""
        d = self.tdim
        affine = np.matmul(self._linear, nodes[:, : d + 1])
        size = np.abs(nodes[:, 1 : d + 1] - nodes[:, :1]).max(axis=(1, 2))
        return np.abs(nodes - affine).max(axis=(1, 2)) <= STRAIGHT * size

    def _newton(
        self,
        points: npt.NDArray[np.float64],
        nodes: npt.NDArray[np.float64],
        X: npt.NDArray[np.float64],
        size: npt.NDArray[np.float64],
    ) -> npt.NDArray[np.float64]:
        """Newton's method for ``F(X) = points`` with the degree-q maps of ``nodes``, from
        ``X``; each point iterates until its step is below rounding; NaN where the
        residual stays above :data:`NEWTON_TOLERANCE` times ``size``."""
        todo = np.arange(len(points))
        for _ in range(NEWTON_STEPS):
            tab = self._geometry.tabulate(1, X[todo])[..., 0]  # (1 + d, n, nodes)
            F = np.einsum("ng,ngd->nd", tab[0], nodes[todo]) - points[todo]
            J = np.einsum("kng,ngd->ndk", tab[1:], nodes[todo])
            dX = np.linalg.solve(J, F[..., None])[..., 0]
            X[todo] -= dX
            todo = todo[np.abs(dX).max(axis=1) >= 1e-15]
            if len(todo) == 0:
                break
        F = np.einsum("ng,ngd->nd", self._geometry.tabulate(0, X)[0, ..., 0], nodes) - points
        X[~(np.abs(F).max(axis=1) <= NEWTON_TOLERANCE * size)] = np.nan  # no convergence
        return X

    def _best_cells(
        self,
        points: npt.NDArray[np.float64],
        dofs: npt.NDArray[np.int64],
        start: npt.NDArray[np.int64],
        x_old: npt.NDArray[np.float64],
        active_old: npt.NDArray[np.bool_],
        nearest: bool = True,
    ) -> tuple[npt.NDArray[Any], ...]:
        """For each point (the new place of the dof ``dofs``, in the cell ``start``), the
        old active cell that holds it (or, outside the old domain, the one it is least far
        outside of), its reference coordinates, its score and the cell's input number
        (:meth:`_choose`; score ``-inf`` where none was found).

        The candidates are the cells of the dof (most points move within them), then for
        the points strictly inside none of them the old active cells sharing a vertex with
        ``start``, and for the points in none of those (the boundary moved by more than a
        cell layer), with ``nearest``, the :data:`NEAREST` old active cells of this rank with
        the nearest centroids."""
        n = len(points)
        best = np.full(n, -1, dtype=np.int64)
        score = np.full(n, -np.inf)
        key = np.full(n, np.inf)
        X = np.zeros((n, self.tdim))
        straight = self._straight_of(x_old) if self._geometry.degree > 1 else None
        state: tuple[Any, ...] = (best, score, key, X, straight)
        inside = self._choose(
            _star_pairs(np.arange(n), dofs, *self._d2c, active_old, False), points, x_old, state
        )
        out = np.setdiff1d(np.arange(n), inside)  # most points stay inside a cell of the dof
        v = self._c2v[start[out]]
        pairs = _star_pairs(np.repeat(out, v.shape[1]), v.ravel(), *self._v2c, active_old)
        self._choose(pairs, points, x_old, state)
        far = np.flatnonzero(score < 0.0)
        old = np.flatnonzero(active_old)
        if nearest and len(far) and len(old):
            centroids = x_old[self._gdofmap[old][:, : self.tdim + 1], : self.tdim].mean(axis=1)
            k = min(NEAREST, len(old))
            near = cKDTree(centroids).query(points[far], k=k)[1].reshape(len(far), k)
            more = np.column_stack([np.repeat(far, k), old[near.ravel()]])
            self._choose(more, points, x_old, state)
        return best, X, score, key

    def _choose(
        self,
        pairs: npt.NDArray[np.int64],
        points: npt.NDArray[np.float64],
        x_old: npt.NDArray[np.float64],
        state: tuple[npt.NDArray[Any], ...],
    ) -> npt.NDArray[np.int64]:
        """Keep for each point of the ``(point, cell)`` pairs the best cell so far in
        ``state = (best, score, key, X, straight)``: the largest score (0 for a cell holding the
        point, within :data:`INSIDE`; its smallest barycentric coordinate outside), then the
        smallest input cell number (a point on the common boundary of cells takes the same
        cell on any number of ranks). Returns the points strictly inside their chosen
        cell."""
        best, score, key, X, straight = state
        if len(pairs) == 0:
            return np.empty(0, dtype=np.int64)
        Xp = self.pull_back(points[pairs[:, 0]], pairs[:, 1], x_old, straight)
        c = self._cell_key[pairs[:, 1]]
        first, lam, s = _best_pairs(pairs[:, 0], Xp, c)
        p = pairs[first, 0]
        better = (s[first] > score[p]) | ((s[first] == score[p]) & (c[first] < key[p]))
        p, first = p[better], first[better]
        best[p], score[p], key[p], X[p] = pairs[first, 1], s[first], c[first], Xp[first]
        return p[lam[first] > INSIDE]

    # -- values ---------------------------------------------------------------------------

    def carry(
        self,
        values: npt.NDArray[np.float64],
        x_old: npt.NDArray[np.float64],
        active_old: npt.NDArray[np.bool_],
        x_new: npt.NDArray[np.float64],
        active_new: npt.NDArray[np.bool_],
    ) -> npt.NDArray[np.float64]:
        """The dof values ``(num_dofs * bs,)`` (owned and ghost) of the function ``values``
        of the geometry ``x_old`` (active cells ``active_old``) for the geometry ``x_new``
        (collective).

        Dofs of cells active for both with unmoved nodes keep their values; the other dofs
        of the new active cells are the old function at their new places (continued from
        the nearest old active cell outside the old domain); dofs of no new active cell
        keep their old values.

        Raises
        ------
        MeshingError
            On every rank when a moved dof finds no old active cell (there are none).
        """
        bs, out = self._bs, values.copy()
        cells = self.moved_cells(x_old, active_old, x_new, active_new)
        dof, cell, slot, best, X, (score, key), points = self._placed(
            cells, x_new, x_old, active_old, nearest=False
        )
        value = np.empty((len(dof), bs))
        near = np.flatnonzero(score >= 0.0)
        phi = self._basis.tabulate(0, X[near])[0, :, :, 0]  # (n, ndofs)
        old = values.reshape(-1, bs)[self._dofmap[best[near]]]  # (n, ndofs, bs)
        value[near] = np.einsum("na,nab->nb", phi, old)
        far = np.flatnonzero(score < 0.0)
        value[far], score[far], key[far] = self._extend(
            points[far], x_old, active_old, values, cells
        )
        self._raise_unplaced(points, score)
        out.reshape(-1, bs)[dof] = value
        if self._comm.size > 1:
            self._from_ghosts(out, dof, (score, key))
        return out

    def carry_slope(
        self,
        slope: npt.NDArray[np.float64],
        values: npt.NDArray[np.float64],
        w_old: npt.NDArray[np.float64],
        x_old: npt.NDArray[np.float64],
        active_old: npt.NDArray[np.bool_],
        x_new: npt.NDArray[np.float64],
        w_new: npt.NDArray[np.float64],
        active_new: npt.NDArray[np.bool_],
    ) -> npt.NDArray[np.float64]:
        """A time derivative along the nodes' paths carried onto other paths (collective).

        ``slope`` is ``d/dt u(x(t), t)`` along paths with nodes ``x_old`` moving at
        ``w_old (num_nodes, gdim)``; along paths through ``x_new`` moving at ``w_new`` it is
        ``slope + (w_new - w_old) · ∇u`` (both ``∂_t u + w · ∇u``), with ``u`` the function
        ``values``. Dofs whose node and velocity are unchanged keep their slope; the others
        take the old slope, velocity and gradient at their new places (continued from the
        nearest old active cell outside the old domain).
        """
        bs, d, out = self._bs, self.tdim, slope.copy()
        scale = self._comm.allreduce(
            float(np.abs(w_new).max(initial=0.0)) + float(np.abs(w_old).max(initial=0.0)),
            op=MPI.MAX,
        )  # the same threshold on every rank
        faster = (np.abs(w_new - w_old) > SAME_PLACE * max(scale, 1e-300)).any(axis=1)
        cells = self.moved_cells(x_old, active_old, x_new, active_new, faster)
        dof, cell, slot, best, X, choice, _ = self._placed(cells, x_new, x_old, active_old)
        if len(dof):
            w_p = np.einsum("ng,ngd->nd", self._N[slot], w_new[self._gdofmap[cell], :d])
            tab = self._basis.tabulate(1, X)[..., 0]  # (1 + d, n, ndofs)
            gtab = self._geometry.tabulate(1, X)[..., 0]  # (1 + d, n, nodes)
            nodes = x_old[self._gdofmap[best], :d]
            J = np.einsum("kng,ngd->ndk", gtab[1:], nodes)
            u = values.reshape(-1, bs)[self._dofmap[best]]  # (n, ndofs, bs)
            ref = np.einsum("kna,nab->nbk", tab[1:], u)  # reference gradient (n, bs, d)
            grad = np.linalg.solve(np.swapaxes(J, 1, 2)[:, None], ref[..., None])[..., 0]
            w_o = np.einsum("ng,ngd->nd", gtab[0], w_old[self._gdofmap[best], :d])
            k = np.einsum("na,nab->nb", tab[0], slope.reshape(-1, bs)[self._dofmap[best]])
            out.reshape(-1, bs)[dof] = k + np.einsum("nbk,nk->nb", grad, w_p - w_o)
        if self._comm.size > 1:
            self._from_ghosts(out, dof, choice)
        return out

    def _placed(
        self,
        cells: npt.NDArray[np.int64],
        x_new: npt.NDArray[np.float64],
        x_old: npt.NDArray[np.float64],
        active_old: npt.NDArray[np.bool_],
        nearest: bool = True,
    ) -> tuple[Any, ...]:
        """The dofs of ``cells`` (each once), one cell holding each and the slot there, and
        the old cells (:meth:`_best_cells`) and reference coordinates of their places in
        ``x_new``, with the choice's scores and cell numbers, and the places; with
        ``nearest``, raises on every rank where a place has no old cell."""
        dofs = self._dofmap[cells]
        dof, at = np.unique(dofs.ravel(), return_index=True)
        cell, slot = cells[at // dofs.shape[1]], at % dofs.shape[1]
        points = np.einsum("ng,ngd->nd", self._N[slot], x_new[self._gdofmap[cell], : self.tdim])
        best, X, score, key = self._best_cells(points, dof, cell, x_old, active_old, nearest)
        if nearest:
            self._raise_unplaced(points, score)
        return dof, cell, slot, best, X, (score, key), points

    def _raise_unplaced(
        self, points: npt.NDArray[np.float64], score: npt.NDArray[np.float64]
    ) -> None:
        """Raise on every rank where a place found no old cell (collective)."""
        found = score > -np.inf
        raise_collective(
            self._comm,
            []
            if found.all()
            else [
                Problem(
                    "{count} dofs have no active cell of the previous step, at {where}: "
                    "the previous domain is empty on this rank's part of the mesh",
                    points[~found],
                    int((~found).sum()),
                )
            ],
        )

    def _extend(
        self,
        points: npt.NDArray[np.float64],
        x_old: npt.NDArray[np.float64],
        active_old: npt.NDArray[np.bool_],
        values: npt.NDArray[np.float64],
        moved: npt.NDArray[np.int64],
    ) -> tuple[npt.NDArray[np.float64], ...]:
        """The old function at ``points`` that found no old cell around them: in the old
        active cell holding it, or, outside the old domain, continued from the one it is
        least far outside of (the largest score, then the smallest input number) among
        the :data:`NEAREST` with the nearest centroids (collective). The candidates are the
        same on every number of ranks: the old active cells within :data:`LAYERS` vertex
        neighbourhoods of the old inactive cells and of ``moved``, gathered from all ranks
        (a band along Gamma: its size grows with Gamma's, not with the mesh's).
        Returns the values ``(n, bs)``, the scores and the cell numbers."""
        d, bs, comm = self.tdim, self._bs, self._comm
        n = len(points)
        if (comm.allreduce(n, op=MPI.SUM) if comm.size > 1 else n) == 0:  # nothing to gather
            return np.zeros((0, bs)), np.full(0, -np.inf), np.full(0, np.inf)
        seed = ~active_old
        seed[moved] = True
        for _ in range(LAYERS):  # the cells sharing a vertex with the seed, layer by layer
            touch = np.zeros(self._vertices.size_local + self._vertices.num_ghosts)
            touch[self._c2v[seed]] = 1.0
            if comm.size > 1:
                touch = vertex_reduce(self._vertices, touch, "max")
            seed = seed | (touch[self._c2v] > 0).any(axis=1)
        band = active_old & seed
        band[self._owned_cells :] = False  # each cell from its owner
        own = np.flatnonzero(band)
        part = (self._cell_key[own], x_old[self._gdofmap[own], :d],
                values.reshape(-1, bs)[self._dofmap[own]])  # fmt: skip
        parts = comm.allgather(part) if comm.size > 1 else [part]
        keys, nodes, vals = (np.concatenate([p[i] for p in parts]) for i in range(3))
        order = np.argsort(keys, kind="stable")  # the same arrays on every number of ranks
        keys, nodes, vals = keys[order], nodes[order], vals[order]
        k = min(NEAREST, len(keys))
        if n == 0 or k == 0:
            return np.zeros((n, bs)), np.full(n, -np.inf), np.full(n, np.inf)
        centroids = nodes[:, : d + 1].mean(axis=1)
        cand = cKDTree(centroids).query(points, k=k)[1].reshape(n * k)
        at = np.repeat(np.arange(n), k)
        curved = None
        if self._geometry.degree > 1:
            curved = np.flatnonzero(~self._straight(nodes)[cand])
        X = self._pull_back(points[at], nodes[cand, : d + 1], curved,
                            None if curved is None else nodes[cand[curved]])  # fmt: skip
        c = keys[cand]
        first, _, s = _best_pairs(at, X, c)
        phi = self._basis.tabulate(0, np.nan_to_num(X[first]))[0, :, :, 0]
        value = np.einsum("na,nab->nb", phi, vals[cand[first]])
        return value, s[first], c[first]

    def _from_ghosts(
        self,
        out: npt.NDArray[np.float64],
        dof: npt.NDArray[np.int64],
        choice: tuple[npt.NDArray[Any], ...],
    ) -> None:
        """Give each dof computed on some rank the value of the rank that chose the best
        cell for it (``choice``: the scores and cell numbers of :meth:`_choose`; the mean
        over the ranks that chose the same cell), on every rank (collective).

        A rank holds the cells around its dofs only up to its ghost layer: the cell holding
        a point may be on another rank, which then gives the value."""
        imap, bs = self.V.dofmap.index_map, self._bs
        score, key = choice
        mine = np.full(imap.size_local + imap.num_ghosts, -np.inf)
        mine[dof] = score
        best = vertex_reduce(imap, mine, "max")
        cell = np.full(len(mine), np.inf)
        cell[dof] = key
        cell[mine != best] = np.inf
        first = vertex_reduce(imap, cell, "min")
        take = ((cell == first) & np.isfinite(cell)).astype(np.float64)
        count = vertex_reduce(imap, take, "sum")
        values = out.reshape(-1, bs)
        total = vertex_reduce(imap, values * take[:, None], "sum")
        hit = count > 0
        values[hit] = total[hit] / count[hit, None]


class MixedTransfer:
    """:class:`NodeTransfer` for a mixed space (Taylor–Hood...): each sub-space's dofs
    carried by the transfer of its collapsed space."""

    def __init__(
        self, mesh: Any, cell_vertices: npt.NDArray[np.int32], W: fem.FunctionSpace
    ) -> None:
        self.parts = []
        for i in range(W.num_sub_spaces):
            Vi, dofs = W.sub(i).collapse()
            rows = np.concatenate([np.asarray(a) for a in dofs]) if isinstance(dofs, list) else dofs
            self.parts.append((NodeTransfer(mesh, cell_vertices, Vi), np.asarray(rows)))
        for transfer, _ in self.parts[1:]:  # one geometry: the straight cells are shared
            transfer._straight_cache = self.parts[0][0]._straight_cache

    def carry(self, values: npt.NDArray[np.float64], *geometry: Any) -> npt.NDArray[np.float64]:
        """:meth:`NodeTransfer.carry` of each sub-space's values."""
        out = values.copy()
        for transfer, rows in self.parts:
            out[rows] = transfer.carry(values[rows], *geometry)
        return out

    def carry_slope(
        self, slope: npt.NDArray[np.float64], values: npt.NDArray[np.float64], *geometry: Any
    ) -> npt.NDArray[np.float64]:
        """:meth:`NodeTransfer.carry_slope` of each sub-space's slope."""
        out = slope.copy()
        for transfer, rows in self.parts:
            out[rows] = transfer.carry_slope(slope[rows], values[rows], *geometry)
        return out


def node_transfer(
    mesh: Any, cell_vertices: npt.NDArray[np.int32], V: fem.FunctionSpace
) -> NodeTransfer | MixedTransfer:
    """The transfer of ``V``: :class:`MixedTransfer` for a mixed space, else
    :class:`NodeTransfer`."""
    if V.ufl_element().is_mixed:
        return MixedTransfer(mesh, cell_vertices, V)
    return NodeTransfer(mesh, cell_vertices, V)


def _ranges(counts: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """``concatenate([arange(c) for c in counts])``, without the loop."""
    ends = np.cumsum(counts)
    return np.arange(ends[-1] if len(ends) else 0) - np.repeat(ends - counts, counts)


def _inverse(J: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Inverses of the matrices ``J (n, d, d)``, ``d`` = 2 or 3, by their adjugates (many
    small matrices: several times faster than ``np.linalg.inv``)."""
    if J.shape[1] == 2:
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        adj = np.stack([np.stack([J[:, 1, 1], -J[:, 0, 1]], axis=1),
                        np.stack([-J[:, 1, 0], J[:, 0, 0]], axis=1)], axis=1)  # fmt: skip
        return adj / det[:, None, None]
    if J.shape[1] == 3:
        c = np.stack([np.cross(J[:, :, 1], J[:, :, 2]), np.cross(J[:, :, 2], J[:, :, 0]),
                      np.cross(J[:, :, 0], J[:, :, 1])], axis=1)  # fmt: skip
        det = np.einsum("ni,ni->n", J[:, :, 0], c[:, 0])
        return c / det[:, None, None]
    return np.linalg.inv(J)


def _best_pairs(
    at: npt.NDArray[np.int64], X: npt.NDArray[np.float64], key: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Of ``(point, cell)`` pairs (``at``: the points, ``X``: the reference coordinates
    there, ``key``: the cells' input numbers), the best pair of each point: the largest
    score (0 for a cell holding the point, within :data:`INSIDE`; its smallest barycentric
    coordinate outside; ``-inf`` where the pull-back did not converge), then the smallest
    cell number. Returns those pairs' indices and every pair's smallest barycentric
    coordinate and score."""
    lam = np.column_stack([1.0 - X.sum(axis=1), X]).min(axis=1)
    lam[np.isnan(lam)] = -np.inf  # the map's continuation did not reach the point
    score = np.where(lam >= -INSIDE, 0.0, lam)
    order = np.lexsort((key, -score, at))
    first = order[np.r_[True, at[order[1:]] != at[order[:-1]]]]
    return first, lam, score


def _star_pairs(
    points: npt.NDArray[np.int64],
    entities: npt.NDArray[np.integer],
    offsets: npt.NDArray[np.int64],
    cells: npt.NDArray[np.int64],
    active: npt.NDArray[np.bool_],
    unique: bool = True,
) -> npt.NDArray[np.int64]:
    """The ``(point, cell)`` pairs of every point of ``points`` with the active cells of
    the entity (vertex or dof) given with it in ``entities`` (``offsets, cells``: the
    entity -> cell adjacency); each pair once unless ``unique`` is false (one entity per
    point: its cells are distinct)."""
    counts = offsets[entities + 1] - offsets[entities]
    cand = cells[np.repeat(offsets[entities], counts) + _ranges(counts)]
    pairs = np.column_stack([np.repeat(points, counts), cand])
    if unique:
        ncells = np.int64(len(active))
        pairs = np.unique(pairs[:, 0] * ncells + pairs[:, 1])
        pairs = np.column_stack([pairs // ncells, pairs % ncells])
    return pairs[active[pairs[:, 1]]]
