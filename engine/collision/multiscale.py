"""Multiscale Picard (paper §5.3, Algorithm 6): fronts kept across Picard iterations.

For every body pair a **front** of node pairs lives through the Picard iterations of
one step: a complete cut of the pair's tree product (every leaf pair lies under exactly
one entry), starting at the two roots. Each iteration evaluates every entry at the
guessed configuration, then

* **widens**: an entry with a surrogate whose test says "contact" or "not converged"
  (bounding spheres first, then the iterative kernel — exact for ``kernel="exact"`` —
  as in the contact search) is replaced by its child pairs: every surrogate of the pair
  unfolds, a leaf stays (the traversal's unfold rule, :mod:`engine.collision.query`) —
  one level per iteration (the paper: "one Picard iteration per unfolding step");
* **narrows**: a complete group of siblings that are all certainly apart folds back to
  its parent ("if all children … do certainly not contribute … they are replaced with
  their parent") when the parent is certainly apart too (checked at the fold), unless
  that parent was folded before in this step and came back: the **veto memory** then
  forbids folding it again, so the front cannot cycle.

Forces: leaf entries give the exact contacts (merged as in a single query); a surrogate
entry in contact gives a **damped surrogate force** (the paper: "we artificially reduce
the force contributions from coarse surrogate levels"): the law is applied to the
overlap scaled by ρ² — δ_eq = δ_s·ρ², ρ = (ε_a + ε_b)/(ε_i + ε_j) the ratio of the leaf
to the surrogate halos — so that, for the paper's law, F = K_s·φ_s·ρ·√m_red with φ_s the
surrogate pair's own overlap fraction; surrogate contacts carry no friction. A step
converges only when the Picard residual is small **and** nothing unfolded in the last
iteration; then every surrogate entry is certainly apart and the forces are exactly the
leaf contacts of the accepted configuration.

Design and rules from the paper (line references and choices): docs/dynamics.md.
"""

from __future__ import annotations

import numpy as np

from engine.collision.query import (
    ULP,
    contact_constants,
    query_parameters,
    unfold_pairs,
    unfolded_ranges,
)
from engine.kernels.collision.batch import query_margin, relative_pose
from engine.kernels.collision.traversal import front_kernel
from engine.kernels.geometry import triangle_batch as tb_kernels

__all__ = ["MultiscaleSearch"]


class _Front:
    """The front of one body pair: ``g`` entries (node pairs) with their parents.

    nodes : (g, 2) int64 — (node of A, node of B) of each entry, a complete cut
    parents : (g, 2) int64 — the pair each entry was unfolded from, (−1, −1) for the roots
        and for a folded pair whose own parent is not known
    quiet : (g,) bool — entry certainly apart at the last evaluation
    up : the parent pair of every pair unfolded this far (a folded pair gets its back)
    folded, veto : pairs folded in this step, and those that came back after a fold
    groups, is_leaf, static : caches (see :meth:`MultiscaleSearch._narrow` and
        :func:`_static`), None when they must be recomputed
    """

    def __init__(self) -> None:
        self.nodes = np.zeros((1, 2), np.int64)
        self.parents = np.full((1, 2), -1, np.int64)
        self.quiet = np.zeros(1, bool)  # certainly apart at the last evaluation
        self.up: dict[tuple[int, int], tuple[int, int]] = {}
        self.folded: set[tuple[int, int]] = set()
        self.veto: set[tuple[int, int]] = set()
        self.groups: tuple | None = None  # sibling groups of the entries (see _narrow)
        self.is_leaf: np.ndarray | None = None  # leaf–leaf entries (None: recompute)
        self.static: tuple | None = None  # (key, the pair's pose-free kernel arguments)


class MultiscaleSearch:
    """Contacts of a scene's configurations with per-pair fronts kept between calls.
    Calling it returns ``(leaf contacts, surrogate contacts, changed)``; the surrogate
    contacts are None when no surrogate pair is in contact.

    Fronts are **warm-started across time steps** (the paper's stated future work): a
    step starts from the fronts the previous step ended with, not from the roots; only
    the veto memory and the fold history are per step (:meth:`begin_step`). Any complete
    cut of the tree product is a valid front — convergence still requires that nothing
    unfolds, so the contacts of a converged step are exactly the leaf contacts whatever
    front it started from. A pair that no iteration of a step
    evaluated (it left the broad phase's candidates) loses its front. ``warm = False``
    restarts every step at the roots (the paper's Algorithm 6 as published; kept to measure
    what the warm start saves)."""

    def __init__(self, scene, warm: bool = True) -> None:
        self.scene = scene
        self.warm = warm
        self.fronts: dict[tuple[int, int], _Front] = {}
        self.seen: set[tuple[int, int]] = set()  # pairs evaluated since begin_step

    def begin_step(self) -> None:
        """Forget the veto memory and fold history (they live for one step) and the
        fronts of pairs the last step never evaluated (all of them when not ``warm``)."""
        if not self.warm:
            self.fronts, self.seen = {}, set()
            return
        if not self.fronts and not self.seen:
            return
        self.fronts = {k: f for k, f in self.fronts.items() if k in self.seen}
        self.seen = set()
        for front in self.fronts.values():
            front.folded.clear()
            front.veto.clear()

    def __call__(self, positions, orientations):
        """Contacts at ``positions (n, 3)`` (centres of mass) and ``orientations (n, 4)``
        (unit quaternions w, x, y, z), float64: ``(leaf, surrogate, changed)`` — the
        :class:`~engine.collision.configuration.Contacts` of the leaf entries, those of the
        surrogate entries in contact (damped; None when there are none), and whether any
        front unfolded. Each candidate pair's front is evaluated, widened, then narrowed."""
        from engine.collision.configuration import SEARCH_COUNTERS, Contacts

        scene = self.scene
        origins, pairs = scene.configuration(positions, orientations)
        counters = dict.fromkeys(SEARCH_COUNTERS, 0)
        leaf_rows, surrogate_rows = [], []
        triangle_pairs, changed = 0, False
        for a, b in pairs.tolist():
            front = self.fronts.setdefault((a, b), _Front())
            self.seen.add((a, b))
            leaf, surrogate, unfolded, folded, count = self._evaluate(
                front, a, b, origins, orientations, counters
            )
            leaf_rows.append(leaf), surrogate_rows.append(surrogate)
            triangle_pairs += count
            changed |= unfolded > 0
            counters["unfoldings"] += unfolded
            counters["folds"] += folded
        counters["triangle_pairs"] = triangle_pairs
        damped = any(len(r[2]) for r in surrogate_rows)
        return (
            _stack(Contacts, pairs, leaf_rows, counters),
            _stack(Contacts, pairs, surrogate_rows, dict(counters)) if damped else None,
            changed,
        )

    def _evaluate(self, front, a, b, origins, orientations, counters):
        """Evaluate, widen and narrow the front of bodies ``a``, ``b`` (mesh-frame
        ``origins (n, 3)``, ``orientations (n, 4)``); adds to ``counters``. Returns ``(leaf
        contacts, surrogate contacts, entries unfolded, groups folded, leaf pairs in
        contact)``, contacts as ``(points (c, 3), normals (c, 3), overlaps (c,))`` float64,
        world frame."""
        scene = self.scene
        ta, tb = scene.trees[scene.tree_index[a]], scene.trees[scene.tree_index[b]]
        key = (id(ta), id(tb), scene.precision, scene.kernel)
        if front.static is None or front.static[0] != key:
            front.static = (key, _static(ta, tb, scene.precision, scene.kernel))
        dtype, extents, body_a, body_b, constants, faces, coarse, leaf = front.static[1]
        rot_a, rotation, shift = relative_pose(
            origins[a], orientations[a], origins[b], orientations[b]
        )
        margin = query_margin(*extents, shift, ULP[dtype])
        contact = (*faces, (*constants, rot_a, origins[a].copy()))
        stats = np.zeros(tb_kernels.N_STATS, np.int64)

        def evaluate(nodes: np.ndarray):
            """(status (g,) int8, leaf contacts, surrogate hits) of node pairs ``nodes``."""
            return front_kernel(
                body_a, body_b, (rotation, shift), margin, nodes, coarse, leaf, contact, stats
            )

        nodes = front.nodes
        status, (found, points, normals, overlaps), hits = evaluate(nodes)
        leaf_contacts = (points, normals, overlaps)
        surrogate = _surrogate_contacts(ta, tb, hits, rot_a, origins[a], scene.centers[a])
        if front.is_leaf is None:
            face_a, face_b = ta.views.structure[1], tb.views.structure[1]
            front.is_leaf = (face_a[nodes[:, 0]] >= 0) & (face_b[nodes[:, 1]] >= 0)
        is_leaf = front.is_leaf
        front.quiet = status == 0

        def certainly_apart(pairs: np.ndarray) -> np.ndarray:
            """(g,) bool: node pairs certainly apart at this configuration."""
            return evaluate(np.ascontiguousarray(pairs, np.int64))[0] == 0

        unfolded = self._widen(front, ta, tb, status, is_leaf)
        folded = self._narrow(front, ta, tb, certainly_apart)
        counters["comparisons"] += int(stats[tb_kernels.STAT_PAIRS])
        counters["iterative"] += int(stats[tb_kernels.STAT_ITERATIVE])
        counters["fallbacks"] += int(stats[tb_kernels.STAT_FALLBACKS])
        counters["sphere_pruned"] += int(stats[tb_kernels.STAT_SPHERES])
        return leaf_contacts, surrogate, unfolded, folded, len(found)

    def _widen(self, front, ta, tb, status, is_leaf) -> int:
        """Replace the surrogate entries in contact or not converged (``status (g,)`` int8 > 0,
        ``is_leaf (g,)`` bool false) by their child pairs — the traversal's unfold rule,
        shared with the kernels (:func:`~engine.collision.query.unfold_pairs`: every
        surrogate of the pair unfolds, a leaf stays). Unlike the kernels' front, this one
        remembers each entry's parent pair, and each unfolded pair's own parent in
        ``front.up``, so that :meth:`_narrow` can fold children back. Returns the number of
        entries unfolded."""
        grow = np.flatnonzero((status > 0) & ~is_leaf)
        if not len(grow):
            return 0
        for r in grow.tolist():
            key = (int(front.nodes[r, 0]), int(front.nodes[r, 1]))
            front.up[key] = (int(front.parents[r, 0]), int(front.parents[r, 1]))
            if key in front.folded:
                front.veto.add(key)  # re-added after a fold: never fold again this step
        grown = front.nodes[grow]
        kids, group = unfold_pairs(ta, tb, grown)
        keep = np.ones(len(front.nodes), bool)
        keep[grow] = False
        front.nodes = np.concatenate([front.nodes[keep], kids])
        front.parents = np.concatenate([front.parents[keep], grown[group]])
        front.groups = front.is_leaf = None
        front.quiet = np.concatenate([front.quiet[keep], np.zeros(len(kids), bool)])
        return len(grow)

    def _narrow(self, front, ta, tb, certainly_apart) -> int:
        """Fold complete sibling groups, all certainly apart at this evaluation, into their
        parent — if the parent itself is certainly apart (checked now: a parent that would
        report contact would only unfold again, the cycle the paper's veto memory breaks
        after the fact) and is not vetoed (it came back after an earlier fold)."""
        if front.groups is None:  # kept until the front changes (only quiet flags vary)
            parents = front.parents
            inner = np.flatnonzero(parents[:, 0] >= 0)
            width = len(tb)
            keys = parents[inner, 0] * width + parents[inner, 1]
            unique, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
            pa, pb = unique // width, unique % width
            complete = counts == unfolded_ranges(ta, pa)[1] * unfolded_ranges(tb, pb)[1]
            front.groups = (inner, keys, unique, inverse, complete, pa, pb, width)
        inner, keys, unique, inverse, complete, pa, pb, width = front.groups
        if not complete.any():
            return 0
        restless = np.bincount(inverse, weights=~front.quiet[inner], minlength=len(unique))
        candidate = complete & (restless == 0)
        if front.veto and candidate.any():
            candidate &= ~np.isin(unique, [i * width + j for i, j in front.veto])
        if not candidate.any():
            return 0
        pairs = np.stack([pa[candidate], pb[candidate]], axis=1)
        fold = unique[candidate][certainly_apart(pairs)]
        if not len(fold):
            return 0
        add = [(int(k // width), int(k % width)) for k in fold.tolist()]
        front.folded.update(add)
        keep = np.ones(len(front.nodes), bool)
        keep[inner[np.isin(keys, fold)]] = False
        front.groups = front.is_leaf = None
        front.nodes = np.concatenate([front.nodes[keep], np.array(add, np.int64)])
        ups = np.array([front.up.get(k, (-1, -1)) for k in add], np.int64)
        front.parents = np.concatenate([front.parents[keep], ups])
        front.quiet = np.concatenate([front.quiet[keep], np.zeros(len(add), bool)])
        return len(add)


def _static(ta, tb, precision: str, kernel: str) -> tuple:
    """What :func:`~engine.kernels.collision.traversal.front_kernel` takes for the trees ``ta``,
    ``tb`` whatever their poses: ``(dtype, extents, body_a, body_b, the contact setup's
    constants, (faces of B, keep_all, normals of A), coarse and leaf parameters)``."""
    dtype = np.dtype(precision).type
    set_a, master = ta.views.geometry.node_set(precision, False), tb.views.geometry.master
    constants = contact_constants(ta, tb)
    return (
        dtype,
        (ta.views.geometry.extent, tb.views.geometry.extent),
        (set_a.coords_rm, set_a.frames_rm, *ta.views.structure, ta.views.spheres),
        (master.coords_rm, master.frames_rm, *tb.views.structure, tb.views.spheres),
        constants,
        (
            len(tb.views.geometry.face_normals),
            kernel != "iterative",
            ta.views.geometry.face_normals,
        ),
        *query_parameters(kernel, dtype),
    )


def _surrogate_contacts(ta, tb, hits, rot_a, origin_a, center_a):
    """Damped contacts of the surrogate pairs in contact among ``hits`` (the
    :func:`~engine.kernels.collision.traversal.front_kernel` layout), in the world frame; where the
    two closest points coincide the normal points away from A's centre of mass
    (``center_a``, mesh frame)."""
    hit = hits[5] == 1
    if not hit.any():
        return _empty()
    i, j = hits[0][hit], hits[1][hit]
    ei, ej = ta.epsilon[i], tb.epsilon[j]
    p, q = hits[3][:, hit].T.astype(float), hits[4][:, hit].T.astype(float)
    gap = q - p
    length = np.linalg.norm(gap, axis=1)
    point = p + (ei / (ei + ej))[:, None] * gap
    direction = np.where((length > 0)[:, None], gap, point - center_a)
    normal = direction / np.maximum(np.linalg.norm(direction, axis=1), 1e-300)[:, None]
    rho = (ta.leaf_epsilon + tb.leaf_epsilon) / (ei + ej)
    overlap = np.clip(ei + ej - hits[2][hit], 0.0, None) * rho**2
    return point @ rot_a.T + origin_a, normal @ rot_a.T, overlap


def _empty():
    """No contacts: ``(points (0, 3), normals (0, 3), overlaps (0,))`` float64."""
    return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)


def _stack(cls, pairs, rows, counters):
    """A ``cls`` (:class:`~engine.collision.configuration.Contacts`) of the body ``pairs
    (k, 2)`` int64 from one ``(points, normals, overlaps)`` row per pair, concatenated."""
    offsets = np.zeros(len(rows) + 1, np.int64)
    np.cumsum([len(r[2]) for r in rows], out=offsets[1:])
    if not rows:
        return cls(pairs, offsets, *_empty(), counters)
    return cls(pairs, offsets, *(np.concatenate([r[k] for r in rows]) for k in range(3)), counters)
