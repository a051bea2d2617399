"""The simulation loop: the one place that knows the order of the stages (DESIGN.md).

Per step: unconstrained velocities of every contact object (thesis eq. 5.2), collision
detection, constrained velocities per contact island (eqs. 5.5-5.6), then integration.
"""

from __future__ import annotations

import copy
import time as _clock
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from softvr.collision import (
    CollisionSurface,
    Plane,
    Sphere,
    TriangleMesh,
    box_vs_box,
    box_vs_plane,
    edges_vs_edges,
    points_vs_mesh,
    points_vs_plane,
    points_vs_sphere,
    sphere_vs_plane,
    sphere_vs_sphere,
    surface_vs_surface,
)
from softvr.collision.contacts import ContactSide, Contacts, unpack_keys
from softvr.contact import ContactSolution, solve_contacts
from softvr.contact.adhesion import Adhesion, AdhesionState, combine
from softvr.device import cpu_workers, resolve_device, single_threaded_blas
from softvr.dynamics.body import ContactObject
from softvr.dynamics.couplings import Coupling
from softvr.dynamics.islands import CouplingIsland, coupling_islands
from softvr.errors import InputError
from softvr.sim._node_step import IllConditioned, NodeStepper
from softvr.sim._rigid_step import LazySolution, RigidStepper
from softvr.sim.model import rigid_model_supported
from softvr.sim.node_model import node_model_supported

__all__ = ["STAGES", "Scene", "SceneState"]

#: The stages of a step, in order (:attr:`Scene.stage_ms`).
STAGES = ("dynamics", "collision", "contact", "integrate")
#: What a body's state is (:meth:`Scene.save_state`): nodes' ``q``, ``v``, ``fixed_velocity``
#: [n, 3] [m, m/s]; a rigid body's ``position`` [3] [m], ``orientation`` [4], ``v`` [6]; a
#: kinematic body's script time; the step count.
_BODY_STATE = ("q", "v", "fixed_velocity", "position", "orientation", "step_count", "_t", "_target")


@dataclass(frozen=True)
class SceneState:
    """A copy of everything a :class:`Scene` changes as it steps (:meth:`Scene.save_state`):
    plain data, independent of the scene afterwards.

    Attributes
    ----------
    time : float [s]
    layout : int
        The scene's body / static layout it was saved from (a restore into another refuses).
    bodies : list of dict
        Per body, its state fields (``_BODY_STATE``) that it has, copied.
    warm : dict
        Warm starts: contact key -> world impulse [3] [N s].
    adhesion : AdhesionState
        Bond intensities and tangential slips by contact key.
    """

    time: float
    layout: int
    bodies: list
    warm: dict
    adhesion: AdhesionState


def _check_adhesion(adhesion):
    if adhesion is not None and not isinstance(adhesion, Adhesion):
        raise InputError("adhesion", "a softvr.contact.Adhesion or None", type(adhesion).__name__)
    return adhesion


@dataclass
class _Collider:
    body: int
    points: object
    margin: float


@dataclass
class Scene:
    """A scene of contact objects, static planes and their contacts.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr import Scene
    >>> from softvr.collision import Plane
    >>> from softvr.dynamics import FemBody, Material
    >>> from softvr.dynamics.points import EmbeddedPoints
    >>> nodes = np.array([[0, 0, .1], [.1, 0, .1], [0, .1, .1], [0, 0, .2]])
    >>> body = FemBody(nodes, [[0, 1, 2, 3]], Material(1e5, 0.3, 1000.0))
    >>> scene = Scene(gravity=(0, 0, -9.81))
    >>> i = scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(4)[:, None], np.ones((4, 1))))
    >>> scene.add_plane(Plane(normal=(0, 0, 1), friction=0.5))
    >>> for _ in range(100):
    ...     _ = scene.step(0.005)
    >>> bool(body.q[:, 2].min() > -1e-3)  # resting on the ground, not through it
    True

    Attributes
    ----------
    gravity : tuple of 3 float [m/s^2]
    bodies : list of ContactObject
    planes : list of Plane
    spheres : list of Sphere
        Static spheres.
    meshes : list of TriangleMesh
        Static triangle meshes (thin sheets, walls).
    ccd : bool
        Continuous collision detection of points against meshes (sweeps over the step).
    edge_contacts : bool
        Edge-edge contacts between collision surfaces (besides vertex-triangle).
    friction : float
        Coulomb coefficient between two bodies.
    pgs_tolerance : float or None [m/s]
        Velocity error at which the contact solve stops (eq. 5.5's iteration: the node
        sweeps, the per-object PGS, the rigid arrays' sweeps); None: the solvers' own 1e-5
        (``softvr.sim._node_step.SWEEP_TOLERANCE``). ``pgs_iterations`` caps it either way.
    rotation_lag : float or None [rad]
        How far a tet's terms may lag its nodes (a scene stepped on node arrays; the per-object
        path ignores it): a step keeps last step's co-rotation R_e (eq. 5.2's R_e K_e R_e^T)
        where it is within this angle of the polar rotation of the tet's deformation gradient
        F, and keeps R_e and the elastic forces as they are while the nodes are near enough
        for F to have moved by less than it since they were computed
        (:func:`softvr.dynamics.node_arrays.record_elements`); blocks of ``A`` whose tets all
        kept R_e and that no coupling or cloth spring adds to are not assembled again. A lag
        theta: R_e within ~2 theta of the polar rotation, forces of a strain within theta.
        None: every tet every step, R_e to round-off.
    last_solution : ContactSolution or None
        The last step's (None before the first; a step on arrays lets go of it as it starts, so
        None after one that failed).
    time : float [s]
    stage_ms : dict[str, float] [ms]
        Wall time of each stage of the last step, in the order they run (:data:`STAGES`):
        ``dynamics`` (unconstrained velocities, eq. 5.2), ``collision`` (detection),
        ``contact`` (the LCP per contact island and adhesion, eqs. 5.5-5.6), ``integrate``.
        Host time: off the CPU's arrays a step after a step size's first is one batch of
        launches (on CUDA one graph), not timed apart: the host's preparation shows under
        ``dynamics``, the batch and the wait for it under ``contact``, none under ``collision``.
    external : dict[int, ndarray]
        Generalized external force per body index, applied every step until removed (the
        shape of the body's ``v``: [6] force and torque [N, N m] for a rigid body, [node_count,
        3] [N] for a deformable one).
    adhesion_state : AdhesionState
        Adhesion intensity beta of every adhesive contact, by contact id.
    couplings : list of Coupling
        Zero-length springs between bodies (thesis 5.3.2); coupled bodies are stepped together,
        one :class:`~softvr.dynamics.CouplingIsland` per group (found on the first step after
        a change).
    rigid_arrays : bool
        Step a scene of rigid, fixed and kinematic bodies on planes, box and sphere primitives
        and rigid collision points (:func:`~softvr.sim.rigid_model_supported`) on whole-scene arrays with
        compiled launches (:class:`~softvr.sim.RigidModel`); on by default. Off, or for any
        other scene, every body steps as its own object (the reference path).
    node_arrays : bool
        Step a scene of FEM and cloth bodies with the kinematic and fixed bodies and planes they
        meet (:func:`~softvr.sim.node_model_supported`) on whole-scene arrays
        (:class:`~softvr.sim.NodeModel`): eq. 5.6's sweeps with node-block D_A, Chebyshev
        accelerated, no factorization; on by default. A scene too stiff for the sweeps (its
        first step measures it: more than 25 sweeps per decade of error) takes a factorization
        kept from that step where it can (CPU; FEM bodies and driven nodes only) and it is less
        work, else the per-object path, as does a scene with this off.
    device : str
        Warp device the node arrays step on (``"cpu"``, ``"cuda"``, ``"cuda:N"``; see
        :attr:`node_arrays`): one kernel source for both. On a GPU the bodies' ``q``, ``v``
        and ``fixed_velocity`` are host copies, uploaded before each step (so a value assigned
        or written in place between steps counts, as on the CPU) and downloaded after it; the
        factored solve is CPU-only, so a scene too stiff for the sweeps steps on the CPU's arrays.
        The rigid arrays and the per-object path step on the CPU whatever this says.
    parallel_islands : bool
        Solve the coupling islands' unconstrained steps in parallel threads. Off by default:
        the per-island work is still mostly Python (assembly), so on the shoulder the threads
        measured 58-63 ms per step in series against 65-77 in parallel (2 cores).
    """

    gravity: tuple = (0.0, 0.0, -9.81)
    bodies: list = field(default_factory=list)
    planes: list = field(default_factory=list)
    spheres: list = field(default_factory=list)
    meshes: list = field(default_factory=list)
    ccd: bool = True
    edge_contacts: bool = True
    friction: float = 0.5
    pgs_iterations: int = 500
    pgs_tolerance: float | None = None
    contact_margin: float = 0.005
    rotation_lag: float | None = None
    last_solution: ContactSolution | LazySolution | None = None
    time: float = 0.0
    stage_ms: dict = field(default_factory=dict)
    _colliders: list = field(default_factory=list)
    _sphere_bodies: list = field(default_factory=list)
    _box_bodies: list = field(default_factory=list)
    _filtered: set = field(default_factory=set)
    _surfaces: list = field(default_factory=list)
    _warm: dict = field(default_factory=dict)
    _adhesion: dict = field(default_factory=dict)
    external: dict = field(default_factory=dict)
    adhesion_state: AdhesionState = field(default_factory=AdhesionState)
    couplings: list = field(default_factory=list)
    parallel_islands: bool = False
    rigid_arrays: bool = True
    node_arrays: bool = True
    device: str = "cpu"
    # Host copies of the node arrays even on the CPU (NodeStepper): a CUDA step's host traffic, run where
    # no GPU is (tests).
    _host_copies: bool = False
    # The node step's kernels in their GPU forms (a thread per contact, candidate pair or node: NodeSolve's,
    # the detection's, the carry's, the adhesion's ``parallel``) even on the CPU (tests).
    _gpu_forms: bool = False
    _units: tuple[list, list] | None = None
    _pool: ThreadPoolExecutor | None = None
    _stepper: RigidStepper | NodeStepper | None = None
    _node_declined: int | None = None  # the layout the node sweeps found too stiff
    _node_on_cpu: int | None = None  # the layout too stiff for the sweeps off the CPU's own arrays
    _layout: int = 0

    def add_body(self, body: ContactObject, *, collision_points=None, collision_triangles=None,
                 collision_sphere: float | None = None, collision_box=None, margin: float | None = None,
                 adhesion: Adhesion | None = None) -> int:
        """Add a contact object and return its index.

        ``collision_points`` (point entities) collide with planes, static spheres and static
        meshes; with ``collision_triangles`` [triangle_count, 3] over those points they also
        form the body's collision surface, which meets the other bodies' surfaces;
        ``collision_sphere`` [m] makes a rigid body a sphere of that radius about its centre,
        colliding with planes and the other sphere bodies; ``collision_box`` (3 half extents
        [m]) makes it a box, colliding with planes and the other box bodies. A body may have
        both a primitive and a surface: the exact primitive meets the planes and the bodies
        with the same primitive, its surface everything else (soft bodies, static spheres and
        meshes, the other primitive). ``adhesion`` makes
        its surface adhesive (thesis ch. 4) where the other side is too
        (:func:`softvr.contact.combine`).
        """
        if not isinstance(body, ContactObject):
            raise InputError("body", "a softvr.dynamics.ContactObject", type(body).__name__)
        self.bodies.append(body)
        self._layout += 1
        self._units = None
        index = len(self.bodies) - 1
        self._adhesion[("body", index)] = _check_adhesion(adhesion)
        margin = self.contact_margin if margin is None else float(margin)
        if adhesion is not None:
            # Bonded contacts must stay detected until they fully debond.
            margin = max(margin, adhesion.debond_gap)
        if collision_points is not None:
            self._colliders.append(_Collider(index, collision_points, margin))
        if collision_triangles is not None:
            if collision_points is None:
                raise InputError("collision_triangles", "collision_points to build them on", "no points")
            self._surfaces.append(CollisionSurface(index, collision_points, collision_triangles))
        for name, shape, store in (("collision_sphere", collision_sphere, self._sphere_bodies),
                                   ("collision_box", collision_box, self._box_bodies)):
            if shape is None:
                continue
            if not hasattr(body, "position") or body.block_size != 6:
                raise InputError(name, "a rigid body (RigidBody, FixedBody, KinematicBody)", type(body).__name__)
            store.append((index, float(shape) if name == "collision_sphere" else np.asarray(shape, float)))
        return index

    def add_coupling(self, coupling: Coupling, *, collide: bool = False) -> None:
        """Couple two bodies of the scene by zero-length springs (thesis 5.3.2).

        ``collide=False`` (the default) switches collision off between the two: parts solidly
        attached over a large surface have no relative motion there (thesis 5.2.1).
        """
        if not isinstance(coupling, Coupling):
            raise InputError("coupling", "a softvr.dynamics.Coupling", type(coupling).__name__)
        index = {id(b): i for i, b in enumerate(self.bodies)}
        ends = [index.get(id(b)) for b in coupling.bodies]
        if None in ends:
            missing = coupling.bodies[ends.index(None)]
            raise InputError(coupling.name, "a coupling between bodies added to the scene",
                             f"{missing.name!r} is not in it")
        self.couplings.append(coupling)
        self._layout += 1
        self._units = None
        if not collide:
            self.disable_collision(*(int(e) for e in ends if e is not None))

    @property
    def path(self) -> str:
        """Which way the scene steps (its last step's, or the next one's where it is still to
        be measured): ``"node arrays on <device>"`` (with ``" (host copies)"`` where
        ``_host_copies`` runs a CUDA step's host traffic on the CPU), ``"rigid arrays on cpu"``
        or ``"per object"`` (also before the first step)."""
        stepper = self._stepper
        if isinstance(stepper, NodeStepper):
            copies = " (host copies)" if stepper.copies and stepper.device == "cpu" else ""
            return f"node arrays on {stepper.device}{copies}"
        return "rigid arrays on cpu" if isinstance(stepper, RigidStepper) else "per object"

    @property
    def collision_surfaces(self) -> tuple:
        """The bodies' collision surfaces in the order added
        (:class:`~softvr.collision.CollisionSurface`: ``body_index``, ``points`` whose
        ``positions()`` [n, 3] [m] move with the body, ``triangles`` [t, 3], ``edge_set.edges``
        [e, 2])."""
        return tuple(self._surfaces)

    def disable_collision(self, a: int, b: int) -> None:
        """Never make contacts between bodies ``a`` and ``b`` (e.g. a soft part coupled to a bone)."""
        for i in (a, b):
            if not 0 <= i < len(self.bodies):
                raise InputError("body index", f"an index in [0, {len(self.bodies) - 1}]", repr(i))
        self._filtered.add((min(a, b), max(a, b)))
        self._layout += 1

    def collision_enabled(self, a: int, b: int) -> bool:
        """Whether bodies ``a`` and ``b`` make contacts (not switched off by
        :meth:`disable_collision` or a coupling)."""
        return (min(a, b), max(a, b)) not in self._filtered

    def _margin(self, body: int) -> float:
        """Detection margin [m] of a body's surface: the scene's, or its adhesion's debond gap."""
        adhesion = self._adhesion[("body", body)]
        return self.contact_margin if adhesion is None else max(self.contact_margin, adhesion.debond_gap)

    def _pair_margin(self, a: tuple, b: tuple) -> float:
        """Detection margin [m] of a pair (keys of ``_adhesion``: surfaces, primitives, statics):
        the scene's, or the combined adhesion's debond gap, so that bonded contacts stay
        detected until they debond (a sphere's contact area is the cap within it,
        :func:`sphere_vs_plane`)."""
        pair = combine(self._adhesion[a], self._adhesion.get(b))
        return self.contact_margin if pair is None else max(self.contact_margin, pair.debond_gap)

    def _pair_enabled(self, a: int, b: int) -> bool:
        return (min(a, b), max(a, b)) not in self._filtered

    def add_sphere(self, sphere: Sphere, *, adhesion: Adhesion | None = None) -> None:
        """Add a static sphere (optionally adhesive)."""
        self._adhesion[("static", id(sphere))] = _check_adhesion(adhesion)
        self.spheres.append(sphere)
        self._layout += 1

    def add_mesh(self, mesh: TriangleMesh, *, adhesion: Adhesion | None = None) -> None:
        """Add a static triangle mesh (optionally adhesive)."""
        if not isinstance(mesh, TriangleMesh):
            raise InputError("mesh", "a softvr.collision.TriangleMesh", type(mesh).__name__)
        self._adhesion[("static", id(mesh))] = _check_adhesion(adhesion)
        self.meshes.append(mesh)
        self._layout += 1

    def add_plane(self, plane: Plane, *, adhesion: Adhesion | None = None) -> None:
        """Add a static plane (optionally adhesive)."""
        plane.unit_normal()  # validates
        self._adhesion[("static", id(plane))] = _check_adhesion(adhesion)
        self.planes.append(plane)
        self._layout += 1

    def _detect(self, v_free: list, dt: float) -> tuple[list, list]:
        """Collision detection of this step (with the unconstrained velocities for speculation).

        Returns the contact sets and, per set, the pair's combined :class:`Adhesion` (or None).
        """
        out = []
        for surface in self._surfaces:
            surface.refit()
        surfaces = {id(s.points): s for s in self._surfaces}
        primitive = {i: "sphere" for i, _ in self._sphere_bodies} | {i: "box" for i, _ in self._box_bodies}
        for c in self._colliders:
            v = c.points.velocities(v_free[c.body])
            found = []
            # Each static's index in its list makes the contact keys unique in the scene.
            if c.body not in primitive:  # a primitive meets the planes exactly
                found += [(points_vs_plane(c.body, c.points, p, margin=c.margin, velocities=v, dt=dt,
                                           static_index=k), p) for k, p in enumerate(self.planes)]
            found += [(points_vs_sphere(c.body, c.points, s, margin=c.margin, velocities=v, dt=dt,
                                        static_index=k), s) for k, s in enumerate(self.spheres)]
            found += [(points_vs_mesh(c.body, c.points, mesh, margin=c.margin, velocities=v, dt=dt, ccd=self.ccd,
                                      static_index=k), mesh) for k, mesh in enumerate(self.meshes)]
            surface = surfaces.get(id(c.points))
            if surface is not None:
                # Points that are vertices of a collision surface stand for its area around them
                # facing the contact (thesis 4.3.1, projected); a contact's point is its feature a.
                for found_set, _ in found:
                    found_set.area = surface.facing_vertex_area(unpack_keys(found_set.ids)["feature_a"],
                                                                found_set.normal)
            out += found
        # Broad phase: each surface's box, grown by the margin and its vertices' motion.
        moving = [s.points.velocities(v_free[s.body_index]) for s in self._surfaces]
        boxes = []
        for s, v in zip(self._surfaces, moving):
            p = s.points.positions()
            reach = self._margin(s.body_index) + dt * float(np.sqrt((v**2).sum(axis=1).max(initial=0.0)))
            boxes.append((p.min(axis=0) - reach, p.max(axis=0) + reach))
        for n, sa in enumerate(self._surfaces):
            for k, sb in enumerate(self._surfaces[n + 1 :], n + 1):
                if not self._pair_enabled(sa.body_index, sb.body_index):
                    continue
                if primitive.get(sa.body_index, "a") == primitive.get(sb.body_index, "b"):
                    continue  # two boxes or two spheres: their primitives meet exactly
                if (boxes[n][0] > boxes[k][1]).any() or (boxes[k][0] > boxes[n][1]).any():
                    continue
                va, vb = moving[n], moving[k]
                pm = self._pair_margin(("body", sa.body_index), ("body", sb.body_index))
                for x, y, vx, vy in ((sa, sb, va, vb), (sb, sa, vb, va)):
                    out.append((surface_vs_surface(x, y, margin=pm, friction=self.friction, dt=dt, ccd=self.ccd,
                                                   velocities_a=vx, velocities_b=vy), None))
                if self.edge_contacts:
                    out.append((edges_vs_edges(sa, sb, margin=pm, friction=self.friction, dt=dt, velocities_a=va,
                                               velocities_b=vb), None))
        for n, (i, r) in enumerate(self._sphere_bodies):
            for k, p in enumerate(self.planes):
                pm = self._pair_margin(("body", i), ("static", id(p)))
                out.append((sphere_vs_plane(i, self.bodies[i], r, p, margin=pm, velocity=v_free[i], dt=dt,
                                            static_index=k), p))
            for j, rj in self._sphere_bodies[n + 1 :]:
                if self._pair_enabled(i, j):
                    out.append((sphere_vs_sphere(i, self.bodies[i], r, j, self.bodies[j], rj, friction=self.friction,
                                                 margin=self._pair_margin(("body", i), ("body", j)),
                                                 velocity_a=v_free[i], velocity_b=v_free[j], dt=dt), None))
        for n, (i, h) in enumerate(self._box_bodies):
            out += [(box_vs_plane(i, self.bodies[i], h, p, margin=self._pair_margin(("body", i), ("static", id(p))),
                                  velocity=v_free[i], dt=dt, static_index=k), p) for k, p in enumerate(self.planes)]
            for j, hj in self._box_bodies[n + 1 :]:
                if self._pair_enabled(i, j):
                    out.append((box_vs_box(i, self.bodies[i], h, j, self.bodies[j], hj, friction=self.friction,
                                           margin=self._pair_margin(("body", i), ("body", j)), velocity_a=v_free[i],
                                           velocity_b=v_free[j], dt=dt), None))
        contacts = [self._movable(c) for c, _ in out]
        adhesions = [combine(self._adhesion[("body", c.a.body)],
                             self._adhesion[("body", c.b.body)] if static is None
                             else self._adhesion.get(("static", id(static))))
                     for c, static in zip(contacts, (s for _, s in out))]
        return contacts, adhesions

    def _movable(self, contacts):
        """Drop contacts that no impulse can act on: both sides fixed nodes / infinite mass."""
        if not len(contacts):
            return contacts
        stuck = np.ones(len(contacts), bool)
        for side in (contacts.a, contacts.b):
            if side is not None:
                unused = ~np.abs(side.jac).any(axis=(2, 3))  # stencil entries of weight 0
                stuck &= (self.bodies[side.body].immovable(side.blocks) | unused).all(axis=1)
        return contacts.select(~stuck) if stuck.any() else contacts

    def step(self, dt: float) -> ContactSolution | LazySolution:
        """Advance every body by ``dt`` [s] with contact; returns the contact solution.

        Runs with OpenBLAS on one thread (:func:`softvr.device.single_threaded_blas`): the
        compiled kernels already use every core. (A scene on arrays calls no BLAS in a step;
        switching the thread count costs ~8 us, a twentieth of a box-stack step.)
        """
        arrays = self._arrays()
        while arrays is not None:
            dt = ContactObject._check_dt(dt)
            # Let go of the last solution first: a node step's that no one else holds then is
            # not copied out of the arrays the step writes (NodeStepper.step).
            self.last_solution = None
            try:
                self.last_solution, self.stage_ms = arrays.step(dt)
            except IllConditioned:  # before anything moved
                # Too stiff for the sweeps: off the CPU's own arrays, try those (the factored
                # solve is CPU-only); else this step goes the per-object way.
                if isinstance(arrays, NodeStepper) and arrays.copies:
                    self._node_on_cpu = self._layout
                else:
                    self._node_declined = self._layout
                self._stepper = None
                arrays = self._arrays()
            else:
                self.time += dt
                return self.last_solution
        with single_threaded_blas():
            return self._step(dt)

    def save_state(self) -> SceneState:
        """A copy of the scene's changing state (bodies, time, warm starts, adhesion), to go
        back to with :meth:`restore_state` (a rewind, a haptic loop's rollback).

        Examples
        --------
        >>> from softvr import Scene
        >>> from softvr.dynamics import RigidBody
        >>> scene = Scene()
        >>> ball = RigidBody(mass=1.0, inertia=[0.1, 0.1, 0.1], position=[0.0, 0.0, 1.0])
        >>> _ = scene.add_body(ball)
        >>> saved = scene.save_state()
        >>> _ = scene.step(0.01)
        >>> scene.restore_state(saved)
        >>> float(ball.position[2]), scene.time
        (1.0, 0.0)
        """
        if self._stepper is not None:
            adhesion, warm = self._stepper.carried_out()
        else:
            adhesion, warm = self.adhesion_state, self._warm
        bodies = [{name: copy.deepcopy(getattr(b, name)) for name in _BODY_STATE if hasattr(b, name)}
                  for b in self.bodies]
        return SceneState(time=self.time, layout=self._layout, bodies=bodies, warm=copy.deepcopy(dict(warm)),
                          adhesion=copy.deepcopy(adhesion))

    def restore_state(self, state: SceneState) -> None:
        """Put the scene back to ``state`` (from :meth:`save_state` on this scene, with the
        same bodies and statics). The next step rebuilds the array path's launches (the node
        path also its Chebyshev bounds: some ms to a few hundred on a large body).

        Raises
        ------
        InputError
            If ``state`` is not a :class:`SceneState` of this scene's current layout.
        """
        if not isinstance(state, SceneState):
            raise InputError("state", "a SceneState from Scene.save_state()", type(state).__name__)
        if state.layout != self._layout or len(state.bodies) != len(self.bodies):
            raise InputError("state", f"a state saved from this scene's layout ({len(self.bodies)} bodies, "
                             f"layout {self._layout})", f"{len(state.bodies)} bodies, layout {state.layout}")
        for body, fields in zip(self.bodies, state.bodies):
            for name, value in fields.items():
                setattr(body, name, copy.deepcopy(value))
        self.time = state.time
        self._stepper = None  # its carried tables hold the present's warm starts
        self._warm = copy.deepcopy(state.warm)
        self.adhesion_state = copy.deepcopy(state.adhesion)
        self.last_solution = None

    def solve_units(self) -> tuple[list, list]:
        """What the solvers step: one :class:`~softvr.dynamics.CouplingIsland` per group of
        coupled bodies, the others alone (thesis 5.3.2). Returns the units and, per body, its
        ``(unit index, first velocity block in the unit)``."""
        if self._units is None:
            units: list = []
            where: list[tuple[int, int] | None] = [None] * len(self.bodies)
            for group in coupling_islands(self.bodies, self.couplings):
                body = self.bodies[group[0]]
                coupled = any(b is body for c in self.couplings for b in c.bodies)
                if len(group) == 1 and (body.infinite_mass or not coupled):
                    where[group[0]] = (len(units), 0)
                    units.append(self.bodies[group[0]])
                    continue
                members = [self.bodies[i] for i in group]
                ids = {id(m) for m in members}
                mine = [c for c in self.couplings if any(id(b) in ids for b in c.bodies)]
                guests = list({id(b): b for c in mine for b in c.bodies if id(b) not in ids}.values())
                island = CouplingIsland(members, mine, guests=guests,
                                        name="coupling island of " + ", ".join(repr(m.name) for m in members))
                for i, m in zip(group, members):
                    where[i] = (len(units), island.block_offset(m))
                units.append(island)
            self._units = (units, where)
        return self._units

    def _to_units(self, contacts: Contacts, where: list) -> Contacts:
        """The contacts with each side on its unit's velocity blocks (a rigid member's 6-velocity
        block becomes a linear and an angular block of 3 inside a coupling island)."""
        sides: list[ContactSide | None] = []
        for side in (contacts.a, contacts.b):
            if side is None:
                sides.append(None)
                continue
            unit, first = where[side.body]
            if self.solve_units()[0][unit] is self.bodies[side.body]:
                sides.append(ContactSide(unit, side.blocks, side.jac))
            elif side.jac.shape[-1] == 3:
                sides.append(ContactSide(unit, side.blocks + first, side.jac))
            else:  # a rigid member: [c, k, 3, 6] -> [c, 2k, 3, 3]
                c, k = side.blocks.shape
                blocks = (first + 2 * side.blocks[:, :, None] + np.arange(2)).reshape(c, 2 * k)
                jac = side.jac.reshape(c, k, 3, 2, 3).transpose(0, 1, 3, 2, 4).reshape(c, 2 * k, 3, 3)
                sides.append(ContactSide(unit, blocks, jac))
        assert sides[0] is not None  # side a is always a body
        return Contacts(sides[0], sides[1], contacts.normal, contacts.gap, contacts.point_a, contacts.point_b,
                        contacts.ids, contacts.friction, contacts.area)

    def _unconstrained_velocities(self, units: list, where: list, dt: float) -> list:
        """Every unit's unconstrained velocity (eq. 5.2; eq. 5.4 for coupling islands), the
        islands in parallel threads when :attr:`parallel_islands` is set and there are several
        (their solves are independent)."""
        external = [self.external.get(i) for i in range(len(self.bodies))]

        def solve(u: int):
            unit = units[u]
            if isinstance(unit, CouplingIsland):
                ext = [external[i] for i, (w, _) in enumerate(where) if w == u]
                return unit.unconstrained_velocity(dt, self.gravity, ext)
            return unit.unconstrained_velocity(dt, self.gravity, external[where.index((u, 0))])

        islands = sum(isinstance(unit, CouplingIsland) for unit in units)
        if self.parallel_islands and islands > 1 and cpu_workers() > 1:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=cpu_workers(), thread_name_prefix="softvr-island")
            return list(self._pool.map(solve, range(len(units))))
        return [solve(u) for u in range(len(units))]

    def _arrays(self) -> RigidStepper | NodeStepper | None:
        """The array stepper when this scene steps on arrays (:attr:`rigid_arrays`,
        :attr:`node_arrays`), rebuilt after the scene changed; what the contacts carry (warm
        starts, adhesion) moves along when the scene changes path."""
        stepper = self._stepper
        enabled = self.rigid_arrays if isinstance(stepper, RigidStepper) else self.node_arrays
        if stepper is not None and enabled and stepper.still_valid():
            return stepper
        if stepper is not None:
            self.adhesion_state, self._warm = stepper.carried_out()
            self._stepper = None
        resolve_device(self.device)  # a device this machine lacks: named before any path steps
        if self.rigid_arrays and rigid_model_supported(self):
            self._stepper = RigidStepper(self)
        elif self.node_arrays and self._node_declined != self._layout and node_model_supported(self):
            self._stepper = NodeStepper(self, on_cpu=self._node_on_cpu == self._layout)
        return self._stepper

    def _step(self, dt: float) -> ContactSolution:
        """One step of the per-object path (every body as its own object)."""
        t0 = _clock.perf_counter()
        units, where = self.solve_units()
        v_units = self._unconstrained_velocities(units, where, dt)
        v_free = [self._body_velocity(v_units, where, i) for i in range(len(self.bodies))]
        t1 = _clock.perf_counter()
        contacts, adhesions = self._detect(v_free, dt)
        t2 = _clock.perf_counter()
        kept = [(c, a) for c, a in zip(contacts, adhesions) if len(c)]
        contacts, adhesions = [c for c, _ in kept], [a for _, a in kept]
        stiffness = self.adhesion_state.stiffnesses(contacts, adhesions)
        warm, self._warm = self._warm, {}
        solved = solve_contacts(units, v_units, [self._to_units(c, where) for c in contacts], dt,
                                iterations=self.pgs_iterations, warm_start=warm, adhesion=stiffness,
                                slip=self.adhesion_state.slip,
                                **({} if self.pgs_tolerance is None else {"tolerance": self.pgs_tolerance}))
        members = [[i for i, (w, _) in enumerate(where) if w == u] for u in range(len(units))]
        solution = ContactSolution(
            velocities=[self._body_velocity(solved.velocities, where, i) for i in range(len(self.bodies))],
            impulses=solved.impulses, frames=solved.frames, iterations=solved.iterations, residual=solved.residual,
            islands=[sorted(i for u in island for i in members[u]) for island in solved.islands],
            contacts=contacts, gaps_after=solved.gaps_after)
        self.adhesion_state.evolve(solution.contacts, adhesions, solution.impulses, solution.gaps_after, dt)
        current = {int(i) for c in contacts for i in c.ids}
        self._warm = {k: v for k, v in warm.items() if k in current}
        t3 = _clock.perf_counter()
        for unit, v in zip(units, solved.velocities):
            unit.integrate(v, dt)
        self.time += dt
        t4 = _clock.perf_counter()
        self.stage_ms = {k: float(ms) for k, ms in zip(STAGES, 1e3 * np.diff([t0, t1, t2, t3, t4]))}
        self.last_solution = solution
        return solution

    def _body_velocity(self, unit_velocities: list, where: list, body: int) -> np.ndarray:
        """Body ``body``'s share of its unit's velocity (its ``v`` shape)."""
        unit, first = where[body]
        v = unit_velocities[unit]
        units = self.solve_units()[0]
        if units[unit] is self.bodies[body]:
            return v
        b = self.bodies[body]
        flat = np.asarray(v, float).ravel()
        return flat[3 * first : 3 * first + b.velocity_size].reshape(np.shape(b.v))
