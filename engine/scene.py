"""Scenes of rigid bodies: state, instancing, contacts between all bodies (paper §2, §6).

A :class:`Scene` owns float64 state arrays — centre-of-mass ``positions (n, 3)``, unit
quaternions ``orientations (n, 4)`` (w, x, y, z), world-frame ``velocities`` and
``angular_velocities (n, 3)`` — plus per-body mass, body-frame inertia about the centre
of mass, a fixed flag and an external force. Bodies share surrogate trees (instancing):
a mesh is built once and its tree shifted to every other ε it is given
(:mod:`engine.trees.halos`), and a body stores only the index of its tree and the offset of its
centre of mass in the mesh frame. Planes and walls are fixed bodies (infinite mass). Mass
properties: exact for closed meshes, from the convex hull of open ones, or given
(:mod:`engine.dynamics.inertia`), their source in ``mass_source (n,) str`` ("mesh", "convex_hull",
"given", "fixed"); ε defaults: :mod:`engine.trees.halos`.

Contacts of a configuration (:class:`~engine.collision.configuration.Contacts`): bounding
spheres of the trees' roots go through the broad phase (never a fixed–fixed pair); the
candidate pairs go through the multiresolution search in one batched call
(:class:`~engine.collision.batch.TreeBank`), or the flat search pair by pair.

The scene composes the layers below it, which never import it (they receive the scene as
an argument): time stepping is :func:`engine.dynamics.picard.step`; with sleeping bodies
:meth:`step` runs it inside :meth:`Sleep.frozen <engine.dynamics.sleep.Sleep.frozen>` and
then updates the sleep state; the ``multiscale`` scheme's persistent fronts are a
:class:`~engine.collision.multiscale.MultiscaleSearch`. The state the dynamics keep between
steps is declared here: ``warm_start`` (:class:`~engine.dynamics.evaluation.WarmStart`) and
``body_cache`` (:class:`~engine.dynamics.bodies.BodyCache`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from engine.arguments import (
    check_kernel,
    check_precision,
    check_quaternions,
    check_rows,
    check_vector,
    coordinate_limit,
)
from engine.collision.batch import TreeBank
from engine.collision.broadphase import CandidateList
from engine.collision.configuration import (
    Contacts,
    batched_contacts,
    flat_contacts,
)
from engine.collision.multiscale import MultiscaleSearch
from engine.collision.pair_cache import DEFAULT_SKIN, PairCache
from engine.dynamics import picard
from engine.dynamics.bodies import BodyCache, body_terms
from engine.dynamics.evaluation import WarmStart
from engine.dynamics.forces import ContactModel, PaperSpring
from engine.dynamics.history import (
    DEFAULT_SEPARATION_SPEED,
    ContactHistory,
    OverlapReport,
    check_speed,
    overlap_report,
)
from engine.dynamics.inertia import body_mass, fixed_center
from engine.dynamics.sleep import Sleep
from engine.errors import InvalidArgumentError
from engine.geometry.distance import DEFAULT_PRECISION
from engine.geometry.mesh import Mesh
from engine.geometry.pose import Pose
from engine.geometry.shapes import plane
from engine.kernels.dynamics import motion as kd
from engine.trees.halos import DEFAULT_RELATIVE_EPSILON, SceneTrees, check_epsilon
from engine.trees.tree import SurrogateTree

__all__ = ["DEFAULT_RELATIVE_EPSILON", "SCHEMES", "Scene", "SceneState"]

SCHEMES = ("explicit", "implicit", "implicit-surrogate", "implicit-midpoint", "multiscale")
DEFAULT_SCHEME = "implicit-midpoint"
"""The scheme on every measured run-time-against-error front (``benchmarks/accuracy.py``,
BENCHMARKS.md): at dt = 1e-3 on the resting box stack, where explicit diverges from 2e-3,
and on the two-body collisions, where backward Euler's dissipation put it off the front."""


@dataclass(frozen=True)
class SceneState:
    """A copy of a scene's state (float64, world frame).

    positions : (n, 3) — centres of mass (a fixed open mesh: its mesh-frame origin)
    orientations : (n, 4) — unit quaternions (w, x, y, z)
    velocities, angular_velocities : (n, 3)
    masses : (n,) — ``inf`` for fixed bodies
    time : float
    """

    positions: np.ndarray
    orientations: np.ndarray
    velocities: np.ndarray
    angular_velocities: np.ndarray
    masses: np.ndarray
    time: float


class Scene:
    """Rigid bodies with contacts, stepped in time (see :meth:`step`).

    Parameters
    ----------
    gravity : (3,) float — acceleration of every free body (default −9.81 along z)
    contact_model : ContactModel — force law (default :class:`~engine.dynamics.forces.PaperSpring`)
    scheme : str — default time-stepping scheme, one of :data:`SCHEMES` (default
        :data:`DEFAULT_SCHEME`, the implicit midpoint rule)
    kernel, precision : the contact search's leaf kernel and arithmetic (default hybrid in
        float64: BENCHMARKS.md; the state, forces and integration are float64 regardless)
    picard_tolerance : float — Picard converges when every body's force and torque
        change by less than this fraction between iterations (the paper's 1 %)
    max_picard_iterations : int
    max_halvings : int — a step whose Picard iteration does not converge is redone as two
        half steps, at most this deep (0: report the failure in the step's stats only)
    threads : int, optional — worker threads of the narrow phase (default: all cores)
    sleep : bool or Sleep — let bodies at rest sleep (:mod:`engine.dynamics.sleep`; off by default)
    substeps : bool — split a step in which some body's surface would move by more than its
        ε into as many equal sub-steps as that takes (else a ``TunnellingWarning``; see
        :func:`engine.dynamics.picard.travel`)
    separation_speed : float — the largest speed at which overlaps present when the state
        is set from outside (bodies added, ``set_state``) are let go (m/s; default
        :data:`~engine.dynamics.history.DEFAULT_SEPARATION_SPEED`, 0.5; ``inf``: at once, as
        the spring pushes)
    skin : float — the multiresolution search keeps, per body pair, the leaf pairs within
        ε_a + ε_b + skin·(ε_a + ε_b) and evaluates only those while the pair has moved
        by less than that skin (:class:`~engine.collision.pair_cache.PairCache`: exactly the same
        contacts); 0 searches every configuration from the roots; default
        :data:`~engine.collision.pair_cache.DEFAULT_SKIN` (0.25)

    Attributes besides the state arrays
    -----------------------------------
    pair_cache : PairCache — the multiresolution search's per-pair leaf lists
    contact_history : ContactHistory or None — the contacts' tangential springs and
        allowances after the last step (:mod:`engine.dynamics.history`)
    gentle_start : bool — the next step gives the overlaps of its start an allowance
    warm_start : WarmStart or None — the last converged Picard step's final evaluation,
        reused by the next step (:mod:`engine.dynamics.evaluation`); cleared when bodies
        are added and by steps that end elsewhere
    body_cache : BodyCache — per-body terms of the dynamics (:mod:`engine.dynamics.bodies`)
    touching : (k, 2) int64 or None — the body pairs with a contact in the last step's
        accepted evaluation (the sleep rule wakes through them)
    sleep : Sleep or None
    """

    def __init__(
        self,
        gravity=(0.0, 0.0, -9.81),
        contact_model: ContactModel | None = None,
        scheme: str = DEFAULT_SCHEME,
        kernel: str = "hybrid",
        precision: str = DEFAULT_PRECISION,
        picard_tolerance: float = 0.01,
        max_picard_iterations: int = 50,
        max_halvings: int = 0,
        threads: int | None = None,
        skin: float = DEFAULT_SKIN,
        substeps: bool = False,
        sleep=False,
        separation_speed: float = DEFAULT_SEPARATION_SPEED,
    ) -> None:
        self.gravity = check_vector(gravity, 3, "gravity")
        model = PaperSpring() if contact_model is None else contact_model
        if not isinstance(model, ContactModel):
            raise InvalidArgumentError("contact_model must be an engine.ContactModel")
        self.contact_model = model
        self.scheme = _scheme(scheme)
        check_kernel(kernel), check_precision(precision)
        self.kernel, self.precision = kernel, precision
        if not (0 < float(picard_tolerance) < 1):
            raise InvalidArgumentError(
                f"picard_tolerance must be in (0, 1), got {picard_tolerance}"
            )
        if int(max_picard_iterations) < 1:
            raise InvalidArgumentError("max_picard_iterations must be >= 1")
        self.picard_tolerance = float(picard_tolerance)
        self.max_picard_iterations = int(max_picard_iterations)
        if int(max_halvings) < 0:
            raise InvalidArgumentError("max_halvings must be >= 0")
        self.max_halvings = int(max_halvings)
        self.threads = threads
        self.substeps = bool(substeps)
        if sleep is True:
            sleep = Sleep()
        if sleep is not False and sleep is not None and not isinstance(sleep, Sleep):
            raise InvalidArgumentError("sleep must be a bool or an engine.dynamics.sleep.Sleep")
        self.sleep = sleep or None
        self.time = 0.0
        self._trees = SceneTrees()  # each mesh built once, shifted per ε (engine.trees.halos)
        self._bank: TreeBank | None = None
        self._multiscale: MultiscaleSearch | None = None
        self._candidates = CandidateList()  # the broad phase, kept while bodies stay near
        self.pair_cache = PairCache(skin)
        self.warm_start: WarmStart | None = None  # the last converged step's final forces
        self.touching: np.ndarray | None = None  # pairs in contact in the last step
        self.contact_history: ContactHistory | None = None  # springs and allowances
        self.gentle_start = True  # the next step gives initial overlaps an allowance
        self.separation_speed = check_speed(separation_speed)
        self.body_cache = BodyCache()
        # (tree_index they were made for, array): kept while the bodies are the same
        self._root_spheres: tuple[np.ndarray, np.ndarray] | None = None
        self._epsilon: tuple[np.ndarray, np.ndarray] | None = None
        n = 0
        self.positions = np.zeros((n, 3))
        self.orientations = np.zeros((n, 4))
        self.velocities = np.zeros((n, 3))
        self.angular_velocities = np.zeros((n, 3))
        self.masses = np.zeros(n)
        self.inertia = np.zeros((n, 3, 3))
        self.inverse_inertia = np.zeros((n, 3, 3))
        self.centers = np.zeros((n, 3))  # centre of mass in the mesh frame
        self.tree_index = np.zeros(n, np.int64)
        self.fixed = np.zeros(n, bool)
        self.external_forces = np.zeros((n, 3))
        self.mass_source = np.zeros(n, "<U11")  # engine.dynamics.inertia.MASS_SOURCES

    # ------------------------------------------------------------------ building
    def __len__(self) -> int:
        return len(self.masses)

    def add_body(
        self,
        body: Mesh | SurrogateTree,
        position=(0.0, 0.0, 0.0),
        orientation=(1.0, 0.0, 0.0, 0.0),
        velocity=(0.0, 0.0, 0.0),
        angular_velocity=(0.0, 0.0, 0.0),
        density: float | None = None,
        mass: float | None = None,
        fixed: bool = False,
        epsilon: float | str | None = None,
        inertia=None,
        center_of_mass=None,
    ) -> int:
        """Add a body; returns its index.

        Parameters
        ----------
        body : Mesh or SurrogateTree — one tree per mesh (or tree) is kept and shifted to
            every ε its bodies are given (:meth:`SurrogateTree.with_leaf_epsilon`)
        position : (3,) — world position of the centre of mass (of the mesh-frame origin
            for a fixed open mesh)
        orientation : (4,) — unit quaternion (w, x, y, z)
        velocity, angular_velocity : (3,) — world frame (ignored for fixed bodies)
        density, mass : float — at most one; default density 1 (ignored for fixed bodies)
        fixed : bool — immovable (infinite mass)
        epsilon : float, "auto" or None — the body's ε. None: a mesh gets the default rule
            (:mod:`engine.trees.halos`: a free body 0.4 % of its diameter; a fixed body a tenth
            of the smallest free body's ε, at most its own size default, resolved again
            whenever bodies are added), a tree keeps its own leaf ε; "auto": the default
            rule for a tree too; a number: that ε (a tree is shifted to it)
        inertia : (3, 3) or (3,) array_like, optional — inertia tensor about the centre of
            mass (mesh axes) or principal moments; needs ``mass``; a free body's mass
            properties otherwise come from its closed mesh or, for an open mesh, its convex
            hull (:mod:`engine.dynamics.inertia`; the source is in :attr:`mass_source`)
        center_of_mass : (3,) array_like, optional — mesh frame; needs ``mass``
        """
        pose = Pose(position, orientation)  # validates both
        rows = (
            pose.position[None],
            pose.orientation[None],
            check_vector(velocity, 3, "velocity")[None],
            check_vector(angular_velocity, 3, "angular_velocity")[None],
        )
        mass_args = (density, mass, inertia, center_of_mass)
        return self._add(body, rows, mass_args, fixed, epsilon)[0]

    def add_bodies(
        self,
        body: Mesh | SurrogateTree,
        positions,
        orientations=None,
        velocities=None,
        angular_velocities=None,
        density: float | None = None,
        mass: float | None = None,
        fixed: bool = False,
        epsilon: float | str | None = None,
        inertia=None,
        center_of_mass=None,
    ) -> np.ndarray:
        """Add ``k`` bodies of one shape at once (``positions (k, 3)``; orientations
        ``(k, 4)``, velocities and angular velocities ``(k, 3)`` default to identity and
        rest); otherwise as :meth:`add_body`. Returns their indices ``(k,)``."""
        positions = np.array(positions, dtype=np.float64, copy=True)
        if positions.ndim != 2:
            raise InvalidArgumentError("positions must be a (k, 3) array")
        k = len(positions)
        positions = check_rows(positions, k, 3, "positions")
        orientations = (
            np.tile([1.0, 0.0, 0.0, 0.0], (k, 1))
            if orientations is None
            else check_quaternions(orientations, k, "orientations")
        )
        zeros = np.zeros((k, 3))
        rows = (
            positions,
            orientations,
            zeros if velocities is None else check_rows(velocities, k, 3, "velocities"),
            zeros
            if angular_velocities is None
            else check_rows(angular_velocities, k, 3, "angular_velocities"),
        )
        mass_args = (density, mass, inertia, center_of_mass)
        return self._add(body, rows, mass_args, fixed, epsilon)

    def _add(self, body, rows, mass_args, fixed, epsilon) -> np.ndarray:
        """Append bodies of one shape with state ``rows``; returns their indices."""
        fixed = bool(fixed)
        epsilon = check_epsilon(epsilon)
        base, mesh = self._trees.base(body, epsilon)
        positions, orientations, velocities, angular_velocities = rows
        k = len(positions)
        if fixed:
            source, center = "fixed", fixed_center(mesh)
            m, inertia, inverse = math.inf, np.eye(3), np.zeros((3, 3))
            velocities, angular_velocities = np.zeros((k, 3)), np.zeros((k, 3))
        else:
            props = body_mass(mesh, *mass_args)
            source, m, center, inertia = props.source, props.mass, props.center, props.inertia
            inverse = np.linalg.inv(inertia)
        first, version = len(self), self._trees.version
        slot = self._trees.place(body, epsilon, base, mesh, fixed, np.arange(first, first + k))
        self._wake()
        self.pair_cache.clear()  # its keys number the pairs by the body count
        self.warm_start, self.touching = None, None
        self.contact_history, self.gentle_start = None, True
        self.positions = np.concatenate([self.positions, positions])
        self.orientations = np.concatenate([self.orientations, orientations])
        self.velocities = np.concatenate([self.velocities, velocities])
        self.angular_velocities = np.concatenate([self.angular_velocities, angular_velocities])
        self.masses = np.concatenate([self.masses, np.full(k, m)])
        self.inertia = np.concatenate([self.inertia, np.tile(inertia, (k, 1, 1))])
        self.inverse_inertia = np.concatenate([self.inverse_inertia, np.tile(inverse, (k, 1, 1))])
        self.centers = np.concatenate([self.centers, np.tile(center, (k, 1))])
        self.tree_index = np.concatenate([self.tree_index, np.full(k, slot, np.int64)])
        self.fixed = np.concatenate([self.fixed, np.full(k, fixed)])
        self.external_forces = np.concatenate([self.external_forces, np.zeros((k, 3))])
        self.mass_source = np.concatenate([self.mass_source, np.full(k, source)])
        index = self._trees.resolve(self.tree_index, self.fixed)  # the fixed bodies' rule
        if index is not None:
            self.tree_index = index
            self._multiscale = None  # its pairs' cached arguments name the replaced trees
        if self._trees.version != version:
            self._bank = None
        return np.arange(first, first + k)

    def add_plane(
        self,
        point=(0.0, 0.0, 0.0),
        normal=(0.0, 0.0, 1.0),
        size: float = 10.0,
        divisions: int = 16,
        epsilon: float | None = None,
    ) -> int:
        """Add a fixed square plane of side ``size`` centred at ``point``, facing ``normal``
        (2·divisions² triangles); returns its index. ``epsilon`` None: the fixed bodies'
        default rule (:mod:`engine.trees.halos`: a tenth of the smallest free body's ε)."""
        n = check_vector(normal, 3, "normal")
        length = float(np.linalg.norm(n))
        if length == 0:
            raise InvalidArgumentError("normal must not be zero")
        n = n / length
        z = np.array([0.0, 0.0, 1.0])
        axis, cos = np.cross(z, n), float(z @ n)
        if np.linalg.norm(axis) < 1e-12:  # (anti)parallel to z
            q = [1.0, 0.0, 0.0, 0.0] if cos > 0 else [0.0, 1.0, 0.0, 0.0]
        else:
            half = math.acos(max(-1.0, min(1.0, cos))) / 2
            axis = axis / np.linalg.norm(axis) * math.sin(half)
            q = [math.cos(half), *axis]
        mesh = plane(size=(size, size), divisions=divisions)
        return self.add_body(mesh, position=point, orientation=q, fixed=True, epsilon=epsilon)

    def set_external_force(self, body: int, force) -> None:
        """Constant world-frame force on ``body`` (added to gravity every step)."""
        self.external_forces[self._body(body)] = check_vector(force, 3, "force")
        self._wake()

    def _wake(self) -> None:
        """Every body awake (the scene changed from outside)."""
        if self.sleep is not None:
            self.sleep.wake_all(len(self))

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> SceneState:
        return SceneState(
            self.positions.copy(),
            self.orientations.copy(),
            self.velocities.copy(),
            self.angular_velocities.copy(),
            self.masses.copy(),
            self.time,
        )

    def set_state(
        self, positions=None, orientations=None, velocities=None, angular_velocities=None
    ) -> OverlapReport | None:
        """Overwrite any of the state arrays (validated in full before anything changes;
        quaternions with a norm within 1e-6 of 1 are renormalised). Fixed bodies keep
        zero velocities.

        New positions or orientations end the contacts' history (springs, allowances):
        the next step starts gently (overlaps let go at ``separation_speed`` at most,
        :mod:`engine.dynamics.history`), and the returned
        :class:`~engine.dynamics.history.OverlapReport` lists the body pairs whose
        surfaces now cross (overlap beyond the reach ε_a + ε_b). Else None."""
        n = len(self)
        new = {}
        for name, value, width in (
            ("positions", positions, 3),
            ("orientations", orientations, 4),
            ("velocities", velocities, 3),
            ("angular_velocities", angular_velocities, 3),
        ):
            if value is not None:
                new[name] = check_rows(value, n, width, name)
        if "orientations" in new:
            new["orientations"] = check_quaternions(new["orientations"], n, "orientations")
        for name in ("velocities", "angular_velocities"):
            if name in new:
                new[name][self.fixed] = 0.0
        for name, value in new.items():
            setattr(self, name, value)
        self._wake()
        if "positions" not in new and "orientations" not in new:
            return None
        self.contact_history, self.gentle_start = None, True
        return overlap_report(self.contacts(self.positions, self.orientations), self.epsilon)

    # ------------------------------------------------------------------ stepping
    def step(self, dt: float, scheme: str | None = None):
        """Advance by ``dt`` with ``scheme`` (default: the scene's); returns the step's
        :class:`~engine.dynamics.picard.StepStats`. With sleeping bodies: the step runs
        with them frozen, then the sleep state is updated (:mod:`engine.dynamics.sleep`)."""
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise InvalidArgumentError(f"dt must be finite and > 0, got {dt}")
        scheme = _scheme(scheme or self.scheme)
        if self.sleep is None:
            return picard.step(self, dt, scheme)
        start = (self.positions.copy(), self.orientations.copy())
        with self.sleep.frozen(self):
            stats = picard.step(self, dt, scheme)
        self.sleep.update(self, body_terms(self).radius, start, dt, self.touching)
        return dataclasses.replace(stats, sleeping=self.sleep.sleeping)

    def kinetic_energy(self) -> float:
        """Translational plus rotational kinetic energy of the free bodies."""
        free = ~self.fixed
        v, w = self.velocities[free], self.angular_velocities[free]
        rot = np.empty((len(self), 3, 3))
        kd.rotation_matrices(self.orientations, rot)
        world = rot[free] @ self.inertia[free] @ rot[free].transpose(0, 2, 1)
        spin = np.einsum("bi,bij,bj->", w, world, w)
        return float(0.5 * (self.masses[free] * (v * v).sum(1)).sum() + 0.5 * spin)

    def momentum(self) -> tuple[np.ndarray, np.ndarray]:
        """Total linear momentum and angular momentum about the origin of the free bodies."""
        free = ~self.fixed
        m, x, v = self.masses[free], self.positions[free], self.velocities[free]
        rot = np.empty((len(self), 3, 3))
        kd.rotation_matrices(self.orientations, rot)
        world = rot[free] @ self.inertia[free] @ rot[free].transpose(0, 2, 1)
        linear = (m[:, None] * v).sum(0)
        angular = np.cross(x, m[:, None] * v).sum(0) + np.einsum(
            "bij,bj->i", world, self.angular_velocities[free]
        )
        return linear, angular

    # ------------------------------------------------------------------ contacts
    def configuration(self, positions, orientations) -> tuple[np.ndarray, np.ndarray]:
        """Mesh-frame origins ``(n, 3)`` of the bodies at ``positions (n, 3)``,
        ``orientations (n, 4)``, and the broad phase's candidate pairs ``(k, 2)``."""
        n = len(self)
        positions = np.ascontiguousarray(positions, dtype=np.float64)
        orientations = np.ascontiguousarray(orientations, dtype=np.float64)
        origins, centres = np.empty((n, 3)), np.empty((n, 3))
        roots = self._roots()
        limit = coordinate_limit(np.float64)
        # one pass, on this thread: 0.1 ms for the paper's 24,576-sphere grid (split over
        # 16 worker threads, it was slower on a 16-core machine: BENCHMARKS.md, issue 15,
        # thirteenth step)
        bad = kd.placed_bodies(
            positions, orientations, self.centers, roots, limit, (origins, centres)
        )
        if bad >= 0:
            raise InvalidArgumentError(
                f"body {bad} is not at a finite position within the broad phase's range"
            )
        return origins, self._candidates.pairs(
            centres, np.ascontiguousarray(roots[:, 3]), self.fixed
        )

    def _roots(self) -> np.ndarray:
        """(n, 4) root bounding sphere (body frame) of each body, kept while the bodies
        are the same (adding bodies replaces ``tree_index``)."""
        cached = self._root_spheres
        if cached is None or cached[0] is not self.tree_index:
            roots = np.array([t.views.spheres[0] for t in self.trees])[self.tree_index]
            cached = self._root_spheres = (self.tree_index, roots)
        return cached[1]

    def contacts(self, positions, orientations, hierarchy: bool = True) -> Contacts:
        """Contacts of the configuration ``positions (n, 3)``, ``orientations (n, 4)``: the
        broad phase's candidate pairs searched in one batch (multiresolution, through the
        pair cache) or, with ``hierarchy=False``, by the flat search pair by pair."""
        origins, pairs = self.configuration(positions, orientations)
        if hierarchy:
            return batched_contacts(
                self.bank,
                self.tree_index,
                pairs,
                origins,
                orientations,
                self.kernel,
                self.threads,
                self.pair_cache,
            )
        return flat_contacts(
            self.trees, self.tree_index, pairs, origins, orientations, self.kernel, self.precision
        )

    @property
    def multiscale(self) -> MultiscaleSearch:
        """The :class:`~engine.collision.multiscale.MultiscaleSearch` whose fronts persist across
        this scene's steps."""
        if self._multiscale is None:
            self._multiscale = MultiscaleSearch(self)
        return self._multiscale

    @property
    def trees(self) -> list[SurrogateTree]:
        """The trees the bodies use (``tree_index`` points into it); do not edit."""
        return self._trees.trees

    @property
    def bank(self) -> TreeBank:
        if self._bank is None:
            self._bank = TreeBank(self.trees, self.precision)
        return self._bank

    @property
    def epsilon(self) -> np.ndarray:
        """(n,) ε of each body (its tree's leaf ε; a copy of the array kept while the bodies
        are the same)."""
        cached = self._epsilon
        if cached is None or cached[0] is not self.tree_index:
            epsilon = np.array([t.leaf_epsilon for t in self.trees])[self.tree_index]
            cached = self._epsilon = (self.tree_index, epsilon)
        return cached[1].copy()

    # ------------------------------------------------------------------ helpers
    def _body(self, body: int) -> int:
        if isinstance(body, bool) or not isinstance(body, int | np.integer):
            raise InvalidArgumentError(f"body must be an index, got {body!r}")
        if not 0 <= body < len(self):
            raise InvalidArgumentError(f"no body {body} (the scene has {len(self)})")
        return int(body)


def _scheme(scheme: str) -> str:
    if scheme not in SCHEMES:
        raise InvalidArgumentError(f"scheme must be one of {', '.join(SCHEMES)}; got {scheme!r}")
    return scheme
