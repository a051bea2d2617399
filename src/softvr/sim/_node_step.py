"""The step of a scene of FEM bodies (with the kinematic and fixed bodies and the planes they
meet) on whole-scene arrays (a fixed launch sequence):

    element terms + A, b of eq. 5.2 (node blocks)  ->  contacts (points vs planes, surface
        vertices vs the other bodies' triangles)
    ->  sweeps of eq. 5.6 (outer Jacobi with D_A = node blocks, inner PGS, Chebyshev), until
        the velocities stop changing  ->  warm starts carried  ->  integration

No factorization and no separate unconstrained solve: the sweeps solve ``A v = b + J^T lambda``
with the contacts' complementarity at once. The Chebyshev weights need bounds of the spectrum
of D_A^-1 A; they are computed (Lanczos) once per step size from the first step's ``A``, with
margins, and widened if a step's sweeps stop contracting.

The bodies keep working as the user-facing API: an FEM body's ``q``, ``v`` and
``fixed_velocity`` are views of the state arrays (a value the user assigns is copied in before
the next step); a kinematic or fixed body follows its script, its collision points (driven
nodes here) set from its pose and velocity before every step.
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

from softvr.collision.contacts import (ContactKind, Contacts, ContactSide, contact_keys, point_jacobian_blocks,
                                      rigid_side, stencil_side, unpack_keys)
from softvr.contact import ContactSolution
from softvr.contact.adhesion import AdhesionState
from softvr.contact.islands import contact_islands
from softvr.contact.node_adhesion import NodeAdhesion
from softvr.contact.node_coarse import coarse_aggregates
from softvr.contact.node_factored import (FactoredSolve, factored_eligible, factored_work, free_matrix,
                                        sweeps_step_work)
from softvr.contact.node_jacobi import NodeSolve, movable_contacts
from softvr.device import HostMirror, LaunchBatch, in_order, pull_all, replayer, resolve_device
from softvr.dynamics.node_arrays import (NODE_DIVERGENCE_REASONS, record_drive, record_elements, record_integrate,
                                         record_start, record_system)
from softvr.dynamics.node_couplings import record_couplings
from softvr.collision.node_detection import record_carry, record_node_detection
from softvr.dynamics import RigidBody
from softvr.errors import InputError
from softvr.sim._node_cloth import NODE_BODIES
from softvr.sim._node_couplings import block_jacobi_factor
from softvr.sim._node_sweeps import choose_sweeps
from softvr.sim._rigid_step import LazySolution, StepSnapshot
from softvr.sim._node_rigid import RigidNodes
from softvr.sim.model import _materials
from softvr.sim.node_model import build_node_model

__all__ = ["IllConditioned", "NodeStepper"]

#: Safety factors on the Lanczos estimates of the spectrum of D_A^-1 A: an underestimated
#: radius makes the Chebyshev iteration diverge, an overestimated one only slows it.
SPECTRUM_MARGIN = (0.8, 1.02)
#: Velocity error [m/s] at which the sweeps stop (the per-object path's PGS tolerance), where
#: the scene sets no ``pgs_tolerance`` of its own.
SWEEP_TOLERANCE = 1e-5
#: Chebyshev sweeps per decade of error above which a scene is left to the per-object path
#: (a sparse LU per body): ~0.3 ms a sweep on the head CT's 1 870 nodes, and some 5 decades
#: to the tolerance, make the sweeps slower than the factorization there (54 per decade: 150 ms
#: against 68 ms a step), while the soft cube (3.5) and the oranges (8.5) gain 5-6x.
MAX_SWEEPS_PER_DECADE = 25.0
#: Implicit restarts of the plain Lanczos for the smallest eigenvalue of the sweeps' spectrum
#: before :func:`spectrum` takes the shift-invert LU instead (a narrow spectrum converges in a
#: few; candy's wide one would take hundreds).
PLAIN_LANCZOS_RESTARTS = 30
#: PGS passes over the contacts per sweep.
SWEEP_PASSES = 2
#: The contact arrays a step's snapshot copies (NodeContacts), and (snapshot name: ContactBuffer
#: field) those of the rigid path's contact rows its primitives' contacts point to.
_CONTACT_FIELDS = ("kind", "column", "point", "other", "face", "bary", "frame", "gap", "friction", "impulse",
                   "gap_after", "rigid_node", "rigid_lever", "area")
_RIGID_CONTACT_FIELDS = {"key": "key", "point_a": "point_a", "point_b": "point_b", "rigid_area": "area"}
#: The arrays a step reads back by contact row (NodeStepper._hosts: their first ``count`` rows).
_BY_CONTACT = frozenset(_CONTACT_FIELDS) | {"stencil_nodes", "stencil_count"}


class IllConditioned(Exception):
    """The scene's step matrix is too stiff for the node sweeps (:data:`MAX_SWEEPS_PER_DECADE`
    for Jacobi; :func:`softvr.sim._node_sweeps.choose_sweeps` for Gauss-Seidel); raised before
    the step has changed the scene."""


def spectrum(model, state) -> tuple[float, float]:
    """Bounds (lo, hi) of the eigenvalues of D_A^-1 A over the free nodes, from this step's
    ``A`` (``state.blocks``): Lanczos on the similar symmetric L^-1 A L^-T (L L^T = D_A), the
    smallest in shift-invert mode, with :data:`SPECTRUM_MARGIN`. ``D_A`` holds a spring-held
    rigid body's two nodes as one 6x6 block, as the sweeps do."""
    # A kinematic body's nodes have no blocks and are driven; a rigid body's have none either
    # (their D_A is all of their A: eigenvalue 1, inside [lo, hi] since the mean eigenvalue,
    # trace(D_A^-1 A) / 3n, is 1), unless coupling springs hold the body: then they are in.
    a, solved = free_matrix(model, state)
    if not solved.any():
        return 1.0, 1.0  # nothing to solve for: every node is driven
    l_inv = block_jacobi_factor(model, state, solved)
    s = (l_inv @ a @ l_inv.T).tocsr()
    # A fixed start vector (ARPACK's default is random): the same scene steps the same way in
    # every run (the bounds set the Chebyshev weights, and so the rounding of every sweep).
    start = np.random.default_rng(0).standard_normal(s.shape[0])
    hi = float(spla.eigsh(s, k=1, which="LA", return_eigenvectors=False, tol=1e-3, v0=start)[0])
    # The smallest by Lanczos on hi - s, which is cheap where the spectrum is narrow (the soft
    # cube: ~20 ms); where lo << hi it converges slowly (candy: 14.7 s), so past
    # PLAIN_LANCZOS_RESTARTS it is found by shift-invert about 0 instead (one sparse LU of the
    # SPD matrix: candy 0.8 s, the same lo; but 43 ms on the soft cube, twice the plain way).
    shifted = (hi * sp.identity(s.shape[0]) - s).tocsr()
    try:
        lo = hi - float(spla.eigsh(shifted, k=1, which="LA", return_eigenvectors=False, tol=1e-6, v0=start,
                                   maxiter=PLAIN_LANCZOS_RESTARTS)[0])
    except spla.ArpackNoConvergence:
        lo = float(spla.eigsh(s.tocsc(), k=1, sigma=0.0, which="LM", return_eigenvectors=False, tol=1e-6,
                              v0=start)[0])
    return max(lo, 1e-6 * hi) * SPECTRUM_MARGIN[0], hi * SPECTRUM_MARGIN[1]


def _primitive_keys(rigid_keys: np.ndarray, body_a: int, body_b: int) -> np.ndarray:
    """Scene keys [c] of primitive contacts from the rigid path's ``rigid_keys`` [c] (which
    number the bodies among the rigid ones): bodies ``body_a`` and ``body_b`` (scene indices;
    -1: side b is a plane, whose index the key keeps), kind and features as they are (what
    the adhesion's ``primitive_key`` packs on the device)."""
    f = unpack_keys(rigid_keys)
    return contact_keys(f["kind"], body_a, f["feature_a"], f["body_b"] if body_b < 0 else body_b, f["feature_b"])


class _NodeSnapshot(StepSnapshot):
    """A node step's snapshot (:class:`StepSnapshot`), with the collision points' positions
    ``x0`` [p, 3] [m] at the step's start. Its ``count`` contacts and ``x0`` are read in the
    stepper's host arrays until :meth:`detach` copies them out, which the stepper does before
    its next step writes those arrays (where the snapshot is still held then: most are not)."""

    def __init__(self, stepper, count: int, velocities: list, sweeps: int, residual: float):
        self._own: dict | None = None
        super().__init__(None, velocities, sweeps, residual)  # type: ignore[arg-type]  # contacts: built on use
        self._stepper, self._count = stepper, count
        self._live = True  # whether the stepper's arrays still hold this step's contacts
        self._x0_own: np.ndarray | None = None

    @property
    def contacts(self) -> dict:
        if self._own is None:
            self._own = self._stepper._contacts_out(self._count)
        return self._own

    @contacts.setter
    def contacts(self, value) -> None:
        self._own = value

    @property
    def _x0(self) -> np.ndarray:
        if self._x0_own is not None:
            return self._x0_own
        return self._stepper._host("point_x")[:self._stepper.model.point_count]

    def detach(self) -> None:
        """Copy the contacts and ``x0`` out of the stepper's arrays (before they are written again)."""
        if self._live:
            own = self.contacts
            for name in _CONTACT_FIELDS:
                own[name] = own[name].copy()
            self._x0_own = self._x0.copy()
            self._live = False

    def _rigid_side(self, rows: np.ndarray, body: int, sign: float) -> ContactSide:
        """Side ``body`` (a rigid body) of contacts ``rows``, at the levers the step used: the
        contacts' rigid side on its angular node, ``sign`` -1 for side b (its lever is stored
        negated, as the triangle's weights are)."""
        c = self.contacts
        on = c["rigid_node"][rows] == self._stepper.model.body_node_start[body] + 1
        return rigid_side(body, sign * np.einsum("cs,csx->cx", on, c["rigid_lever"][rows]))

    def _at_start(self, rows: np.ndarray, side: ContactSide, sign: float) -> ContactSide:
        """``side``, or for a rigid body its side at the step's levers (:meth:`_rigid_side`)."""
        rigid = type(self._stepper.scene.bodies[side.body]) is RigidBody
        return self._rigid_side(rows, side.body, sign) if rigid else side

    def sets(self) -> list[np.ndarray]:
        """Rows of each contact set, in body order: one per (body, plane), then per (body, body
        its vertices meet), then per (body, body its edges meet), then per (body, static sphere),
        then per (body, static mesh) (points or edges ascending); contacts whose stencil is all
        driven nodes are left out."""
        if self._sets is None:
            s = self._stepper
            c = self.contacts
            body = s.contact_body(c)
            order = np.lexsort((c["point"], c["other"], c["kind"], body))
            order = order[c["movable"][order]]
            statics = len(s.scene.planes) + len(s.scene.spheres) + len(s.scene.meshes)
            pair = (body[order] * 6 + c["kind"][order]) * (statics + len(s.scene.bodies) + 1) + c["other"][order]
            cuts = np.flatnonzero(np.diff(pair)) + 1
            self._sets = [rows for rows in np.split(order, cuts) if len(rows)]
        return self._sets

    def pushing_normals(self, body: int) -> np.ndarray:
        """:meth:`ContactSolution.pushing_normals`, from ``body``'s rows alone: the rows of
        :meth:`sets` (in their order) that ``body`` is a side of (a body never meets itself)."""
        s = self._stepper
        # Where the contacts were not built (a haptic tool asks every step; most steps read
        # nothing else), the pushing rows are read in the step's arrays, and whether they are
        # movable asked of the body's few alone.
        c = self._own
        if c is None:
            names = ("kind", "other", "point", "column", "frame", "impulse")
            c = {name: array[:self._count] for name, array in zip(names, s._hosts(names))}
        rows = np.flatnonzero(c["impulse"][:, 0] > 0)
        # The pushing rows in plain Python: side a's body as contact_body gives it, the sets'
        # order (body a, kind, other, point; a stable sort, as np.lexsort, so ties keep the rows' order).
        picked = []
        for row, kind, other, point, column in zip(rows.tolist(), *(c[name][rows].tolist() for name in
                                                                    ("kind", "other", "point", "column"))):
            first = column if kind == 3 else int(s.edge_body[point] if kind == 2 else s.point_body[point])
            side_b = kind in (1, 2, 3) and other == body
            if first == body or side_b:
                picked.append((first, kind, other, point, row, side_b))
        if picked:
            mine = [x[4] for x in picked]
            movable = c["movable"][mine] if "movable" in c else s._movable(np.array(mine))
            picked = [x for x, keep in zip(picked, movable.tolist()) if keep]
        picked.sort(key=lambda x: x[:4])
        normals = c["frame"][[x[4] for x in picked], 0]
        flip = [k for k, x in enumerate(picked) if x[5]]
        if flip:
            normals[flip] = -normals[flip]
        return normals

    def set_bodies(self) -> list[tuple[int, int | None]]:
        c, first = self.contacts, [rows[0] for rows in self.sets()]
        kind, other = c["kind"][first], c["other"][first]
        body = self._stepper.contact_body({name: c[name][first] for name in ("point", "kind", "column")})
        # Vertex-triangle and edge-edge pairs meet a body; primitives a body or (other < 0) a
        # static; planes, static spheres and meshes are statics.
        meets = (kind == 1) | (kind == 2) | ((kind == 3) & (other >= 0))
        return [(a, b if m else None) for a, b, m in zip(body.tolist(), other.tolist(), meets.tolist())]

    def _build(self) -> ContactSolution:
        s = self._stepper
        c = self.contacts
        model = s.model
        sets = []
        for rows in self.sets():
            kind, other = int(c["kind"][rows[0]]), int(c["other"][rows[0]])
            normal, gap, friction = c["frame"][rows, 0], c["gap"][rows], c["friction"][rows]
            if kind == 3:  # primitives of rigid bodies (the rigid path's contacts)
                body = int(c["column"][rows[0]])
                side_b = None if other < 0 else self._rigid_side(rows, other, -1.0)
                sets.append(Contacts(self._rigid_side(rows, body, 1.0), side_b, normal, gap, c["point_a"][rows],
                                     c["point_b"][rows], _primitive_keys(c["key"][rows], body, other), friction,
                                     c["area"][rows]))
                continue
            if kind == 2:  # edge pairs: both sides are two surface vertices
                edge_a, edge_b = c["point"][rows], c["face"][rows]
                body = int(s.edge_body[edge_a[0]])
                st = c["bary"][rows]
                sides, points = [], []
                for b, edge, t in ((body, edge_a, st[:, 0]), (other, edge_b, st[:, 1])):
                    ends = s.edges[edge] - model.body_point_start[b]
                    weights = np.column_stack([1.0 - t, t])
                    sides.append(self._at_start(rows, stencil_side(b, model.surfaces[b].points, ends, weights),
                                                1.0 if b == body else -1.0))
                    points.append(np.einsum("ck,ckx->cx", weights, self._x0[s.edges[edge]]))
                keys = contact_keys(ContactKind.EDGE_EDGE, body, edge_a - int(s.edge_start[body]), other,
                                    edge_b - int(s.edge_start[other]))
                sets.append(Contacts(sides[0], sides[1], normal, gap, points[0], points[1], keys, friction,
                                     c["area"][rows]))
                continue
            point = c["point"][rows]
            body = int(s.point_body[point[0]])
            local = point - model.body_point_start[body]
            x = self._x0[point]
            point_b = x - gap[:, None] * normal
            if kind == 0:
                side_b, keys = None, contact_keys(ContactKind.POINT_PLANE, body, local, other, 0)
            elif kind == 4:
                side_b, keys = None, contact_keys(ContactKind.POINT_SPHERE, body, local, other, 0)
            elif kind == 5:  # the mesh's surface, its half thickness behind the contact's gap
                point_b = x - (gap + s.scene.meshes[other].thickness)[:, None] * normal
                side_b, keys = None, contact_keys(ContactKind.POINT_MESH, body, local, other, 0)
            else:
                surface = model.surfaces[other]
                faces = c["face"][rows] - int(s.triangle_start[other])
                side_b = self._at_start(rows, stencil_side(other, surface.points, surface.triangles[faces],
                                                           c["bary"][rows]), -1.0)
                keys = contact_keys(ContactKind.VERTEX_TRIANGLE, body, local, other, 0)
            side_a = self._at_start(rows, ContactSide(body, *point_jacobian_blocks(s.colliders[body].points, local)), 1.0)
            sets.append(Contacts(side_a, side_b, normal, gap, x, point_b, keys, friction, c["area"][rows]))
        islands = contact_islands(len(self.velocities),
                                  [(x.a.body, None if x.b is None else x.b.body) for x in sets])
        return ContactSolution(velocities=self.velocities, impulses=self.per_set("impulse"),
                               frames=self.per_set("frame"), iterations=self.sweeps, residual=self.residual,
                               islands=[sorted(i) for i in islands], contacts=sets,
                               gaps_after=self.per_set("gap_after"))


class NodeStepper:
    """Steps a scene of FEM bodies with kinematic and fixed bodies and planes
    (:func:`~softvr.sim.node_model_supported`) on its arrays; built from the scene's current
    state and warm starts."""

    def __init__(self, scene, on_cpu: bool = False):
        self.scene = scene
        # ``on_cpu``: the CPU's own arrays whatever the scene's device (one too stiff for the
        # sweeps takes the factored solve there).
        self.device = "cpu" if on_cpu else resolve_device(scene.device)
        # Host copies of what the Python side reads and writes (the bodies' q and v, the
        # external forces, the contacts a step reads back): on a GPU, or where the scene asks
        # for them on the CPU (tests run a CUDA step's host traffic there).
        self.copies = not on_cpu and (bool(scene._host_copies) or self.device != "cpu")
        self.model, self.state = build_node_model(scene, self.device)
        self._settings = self._scene_settings()
        self.colliders = {c.body: c for c in scene._colliders}
        self.fem = [isinstance(b, NODE_BODIES) for b in scene.bodies]  # free nodes: FEM and cloth
        self.fixed_nodes = self.model.fixed.numpy() != 0
        self._free_nodes = ~self.fixed_nodes
        self._stencil_slots = np.arange(self.state.contacts.stencil_nodes.shape[1])
        self.point_body = self.model.point_body.numpy()
        self.triangle_start = self.model.body_triangle_start.numpy()
        self.edges = self.model.edges.numpy()
        self.edge_body = self.model.edge_body.numpy()
        self.edge_start = self.model.body_edge_start.numpy()
        self._bind_bodies()
        self.rigid = RigidNodes(scene, self.model.rigid, self.copies) if self.model.rigid is not None else None
        self._carry_in(scene._warm)
        self.adhesion = self._adhesion()
        if self.adhesion is not None:
            self.adhesion.carry_in(scene.adhesion_state, scene._warm)
        self._adhesion_replays: tuple = (None, None)  # (dt, NodeAdhesion.record(dt))
        # [key, elements, assemble, rhs, detect, solver, carry, integrate, couplings, start] (_record)
        self._recorded: list[Any] = []
        # (the recorded list, the adhesion replays, their groups: _stages)
        self._staged: tuple[Any, Any, Any] | None = None
        self._after: tuple[tuple, LaunchBatch] | None = None  # _after_sweeps' batch and its key
        self._whole: tuple[tuple, LaunchBatch] | None = None  # _whole_step's batch and its key
        self._spectrum: dict[float, Any] = {}  # the sweeps' choice per step size (choose_sweeps)
        self._issued: Callable[[], _NodeSnapshot | None] = lambda: None  # a weak reference to the last step's snapshot

    def contact_body(self, contacts: dict) -> np.ndarray:
        """Side a's body of each contact of a snapshot's ``contacts``."""
        feature = contacts["point"]
        edge = contacts["kind"] == 2
        primitive = contacts["kind"] == 3  # side a's body is the column
        point = self.point_body[np.where(edge | primitive, 0, feature)] if len(self.point_body) else 0
        return np.where(primitive, contacts["column"],
                        np.where(edge, self.edge_body[np.where(edge, feature, 0)] if len(self.edge_body) else 0, point))

    def _scene_settings(self) -> tuple:
        s = self.scene
        return (s._layout, float(s.contact_margin), float(s.friction), bool(s.edge_contacts),
                tuple(len(b.q) if isinstance(b, NODE_BODIES) else 0 for b in s.bodies), s.device, bool(s._host_copies))

    def still_valid(self) -> bool:
        """Whether the arrays still describe the scene."""
        return self._settings == self._scene_settings()

    def _bind_bodies(self) -> None:
        st = self.state
        # The FEM and cloth bodies' q, v and fixed_velocity are views of these (pushed before a
        # step: a user may have written them in place; pulled after it).
        self._state_mirrors = [HostMirror(a, self.copies) for a in (st.q, st.v, st.fixed_velocity)]
        self._q, self._v, self._fixed_v = (m.host for m in self._state_mirrors)
        self._external_mirror = HostMirror(st.external, self.copies)
        self._external = self._external_mirror.host
        c = st.contacts
        self._host_arrays = {name: getattr(c, name) for name in _CONTACT_FIELDS + ("count", "stencil_nodes",
                                                                                   "stencil_count")}
        self._host_arrays.update(point_x=st.point_x, diverged=st.diverged)
        if self.model.rigid is not None:
            self._host_arrays.update({name: getattr(self.model.rigid.state.contacts, field)
                                      for name, field in _RIGID_CONTACT_FIELDS.items()})
        # Read back after a step (on the CPU views of the arrays' own memory): those asked for
        # together with one wait (pull_all), once a step.
        self._host_mirrors = {name: HostMirror(array, self.copies) for name, array in self._host_arrays.items()}
        self._pulled: set[str] = set()  # (those read back since the step: _hosts)
        # The host side of state.kinematic_* that _drive fills: on the CPU the arrays' own memory
        # (three upload calls cost ~10 us a step), else copies pushed after.
        self._pose_mirrors = [HostMirror(a, self.copies) for a in (st.kinematic_position, st.kinematic_rotation,
                                                                     st.kinematic_velocity)]
        self._drive_nodes = record_drive(self.model, st)
        self._v_before = wp.zeros_like(st.v)  # velocities at the start of the last step [n] [m/s]
        self._carried = False  # whether _v_before belongs to this state (a step ran since it was set)
        start = self.model.body_node_start
        self._views = {i: (self._q[start[i]:start[i + 1]], self._v[start[i]:start[i + 1]],
                           self._fixed_v[start[i]:start[i + 1]]) for i, f in enumerate(self.fem) if f}
        for i, (q, v, fv) in self._views.items():
            body = self.scene.bodies[i]
            body.q, body.v, body.fixed_velocity = q, v, fv
        self._pushed = True

    def _sync_in(self) -> None:
        """Copy in any position or velocity the user assigned since the last step."""
        if self.rigid is not None:
            self.rigid.sync_in()
        for i, views in self._views.items():
            body = self.scene.bodies[i]
            for name, view in zip(("q", "v", "fixed_velocity"), views):
                value = getattr(body, name)
                if value is not view:
                    value = np.asarray(value, float)
                    if value.shape != view.shape:
                        raise InputError(f"{body.name}.{name}", f"an array of shape {view.shape}",
                                         f"shape {value.shape}")
                    view[:] = value
                    setattr(body, name, view)
                    self._carried = False  # a new state: last step's change says nothing

    def _drive(self, dt: float) -> dict:
        """The kinematic and fixed bodies' velocities [6] over the step (their scripts), their
        poses and velocities uploaded for ``_drive_nodes`` (:func:`record_drive`: their collision
        and coupling points' nodes set to where the points are and how they move), which the
        step launches first (alone, or first in its batch)."""
        out: dict[int, np.ndarray] = {}
        if not self.model.kinematic:
            return out
        position, rotation, velocity = (m.host for m in self._pose_mirrors)
        for j, i in enumerate(self.model.kinematic):
            body = self.scene.bodies[i]
            out[i] = v = body.unconstrained_velocity(dt, self.scene.gravity)
            position[j], rotation[j], velocity[j] = body.position, body.rotation, v
        for mirror in self._pose_mirrors:
            mirror.push()
        return out

    def _keys(self, points: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """Contact keys of global points against carried-table columns: planes (kind
        POINT_PLANE, as points_vs_plane), then bodies (kind VERTEX_TRIANGLE, as
        surface_vs_surface), then static spheres (kind POINT_SPHERE, as points_vs_sphere) and
        meshes (kind POINT_MESH, as points_vs_mesh)."""
        start = self.model.body_point_start
        body = self.point_body[points]
        local = points - start[body]
        planes = len(self.scene.planes)
        spheres = planes + len(self.scene.bodies)
        meshes = spheres + len(self.scene.spheres)
        keys = np.empty(len(points), np.int64)
        for kind, rows, first in ((ContactKind.POINT_PLANE, columns < planes, 0),
                                  (ContactKind.VERTEX_TRIANGLE, (columns >= planes) & (columns < spheres), planes),
                                  (ContactKind.POINT_SPHERE, (columns >= spheres) & (columns < meshes), spheres),
                                  (ContactKind.POINT_MESH, columns >= meshes, meshes)):
            if rows.any():
                keys[rows] = contact_keys(kind, body[rows], local[rows], columns[rows] - first, 0)
        return keys

    def _carry_in(self, warm: dict) -> None:
        """The per-object path's warm starts (world impulses by key) into the carried table
        (points vs planes, spheres and meshes, vertices vs bodies; edge pairs start cold)."""
        p, columns = self.model.point_count, self.state.contacts.carried.shape[1]
        if not warm or not p:
            return
        carried = HostMirror(self.state.contacts.carried, self.copies)
        table = carried.host
        points, cols = np.meshgrid(np.arange(p), np.arange(columns), indexing="ij")
        keys = self._keys(points.ravel(), cols.ravel()).reshape(p, columns)
        for (i, j), key in np.ndenumerate(keys):
            if int(key) in warm:
                table[i, j] = warm[int(key)]
        carried.push(wait=True)  # the mirror goes with this call

    def _adhesion(self) -> NodeAdhesion | None:
        """The scene's adhesion on the arrays; None in a scene without any."""
        s = self.scene
        if all(a is None for a in s._adhesion.values()):
            return None
        rows, table = _materials(s)

        def row(key) -> int:
            adhesion = s._adhesion.get(key)
            return -1 if adhesion is None else rows[id(adhesion)]

        planes, spheres, meshes = ([row(("static", id(x))) for x in statics] for statics in (s.planes, s.spheres,
                                                                                             s.meshes))
        return NodeAdhesion(self.model, self.state, table, [row(("body", i)) for i in range(len(s.bodies))], planes,
                            spheres, meshes, parallel=s._gpu_forms or None)

    def _surface_margin(self) -> float:
        """Detection margin [m] between surfaces: the largest of the surface pairs' (the scene's,
        or an adhesive pair's debond gap, so that bonds stay detected while they stretch, as per
        object; a non-adhesive pair in the same scene then gets speculative contacts that far
        out, which only act if they would close)."""
        a, b = np.nonzero(self.model.pair_enabled.numpy())
        return max([self.scene._pair_margin(("body", int(i)), ("body", int(j))) for i, j in zip(a, b)],
                   default=float(self.scene.contact_margin))

    def carried_out(self) -> tuple[AdhesionState, dict]:
        """The adhesion state (intensities and slips by key) and the warm starts (world impulses
        by key) for the per-object path."""
        table = self.state.contacts.carried.numpy()
        i, j = np.nonzero(np.abs(table[:self.model.point_count]).sum(axis=2) > 0)
        warm = {int(k): table[a, b].copy() for k, a, b in zip(self._keys(i, j), i, j)}
        c = self.state.contacts
        partner = c.edge_partner.numpy()[:len(self.edges)]
        e, k = np.nonzero(partner >= 0)
        if len(e):
            a, b = self.edge_body[e], self.edge_body[partner[e, k]]
            keys = contact_keys(ContactKind.EDGE_EDGE, a, e - self.edge_start[a], b, partner[e, k] - self.edge_start[b])
            table = c.edge_carried.numpy()
            warm.update({int(key): table[x, y].copy() for key, x, y in zip(keys, e, k)})
        return (AdhesionState() if self.adhesion is None else self.adhesion.carried_out()), warm

    def _record(self, dt: float) -> None:
        s = self.scene
        key = (dt, tuple(s.gravity), s.pgs_iterations, s.ccd, s.rotation_lag)
        if self._recorded and self._recorded[0] == key:
            return
        m, st = self.model, self.state
        lag = bool(s.rotation_lag)
        turned = wp.zeros(len(m.tets), dtype=wp.int32, device=m.device) if lag else None
        elements = record_elements(m, st, keep=float(s.rotation_lag) if lag else 0.0, turned=turned)
        assemble, rhs = record_system(m, st, dt, s.gravity, turned=turned)
        # The springs' terms (eq. 5.4) add to what the assembly, the right-hand side and the
        # rigid bodies' system wrote (none: driven to driven only).
        couplings = in_order(*record_couplings(m, st, dt)) if len(m.couplings.node) else in_order()
        parallel = s._gpu_forms or None  # (None: the device's own form)
        detect = record_node_detection(m, st, dt, s.gravity, self._surface_margin(), s.friction, s.ccd, parallel)
        carry = record_carry(m, st, parallel)
        integrate = [replayer(record_integrate(m, st, dt, buf)) for buf in st.sweep_buffers]
        if self.rigid is not None:
            self.rigid.record(st, dt, s.gravity)
        start = record_start(m, st, dt, s.gravity, self._v_before, parallel)
        self._recorded = [key, elements, assemble, rhs, detect, None, carry, integrate, couplings, start]

    def _stages(self) -> tuple[Callable[[], None], Callable[[], None], list[Callable[[], None]]]:
        """The recorded launches before and after the sweeps, grouped: the dynamics (element
        terms, assembly, right-hand side), the collision (the couplings' terms, which add to the
        rigid bodies' system, detection, adhesion's preparation), and per sweep buffer the
        settling (the warm starts carried, the integration). Off the CPU's own arrays each group
        is one :class:`~softvr.device.LaunchBatch` (on CUDA one graph launch; none reads anything
        back), on the CPU the launches one by one."""
        recorded = self._recorded
        if self._staged is not None and self._staged[0] is recorded and self._staged[1] is self._adhesion_replays:
            return self._staged[2]
        _, elements, assemble, rhs, detect, _, carry, integrate, couplings, _ = recorded
        prepare = [self._adhesion_replays[1][0]] if self.adhesion is not None else []
        groups = ([elements, assemble, rhs], [couplings, detect, *prepare],
                  *([carry, integrate[r]] for r in range(3)))
        one: Callable[[list], Callable[[], None]] = (lambda group: LaunchBatch(group, self.device)) if self.copies \
            else (lambda group: in_order(*group))
        dynamics, collision, *settle = [one(group) for group in groups]
        self._staged = (recorded, self._adhesion_replays, (dynamics, collision, settle))
        return self._staged[2]

    def _after_sweeps(self, solve: NodeSolve) -> LaunchBatch:
        """The launches after a solve decided on the device (``NodeSolve.solve``'s ``then``), as one
        batch (on CUDA one graph): adhesion's evolve, the settling (warm starts carried, the
        integration) and the rigid bodies' velocities and integration, each for the sweep buffer
        ``solve.buffer_flags`` mark (``wp.capture_if``), where the host would pick them by the
        sweeps' count."""
        key = (self._recorded, self._adhesion_replays, solve)
        if self._after is not None and all(a is b for a, b in zip(self._after[0], key)):
            return self._after[1]
        _, _, _, _, _, _, carry, integrate, _, _ = self._recorded
        flags = solve.buffer_flags
        chosen = [in_order(carry, integrate[r]) for r in range(3)]
        if self.adhesion is not None:
            chosen = [in_order(self._adhesion_replays[1][1][r], chosen[r]) for r in range(3)]

        def by_flag() -> None:
            for flag, launches in zip(flags, chosen):
                wp.capture_if(flag, on_true=launches)

        batch = LaunchBatch([by_flag, *([self.rigid.integrate_launches(flags)] if self.rigid is not None else [])],
                            self.device)
        self._after = (key, batch)
        return batch

    def _whole_step(self) -> LaunchBatch | None:
        """The step's launches as one batch (on CUDA one graph, replayed every step): the driven
        nodes, the dynamics, the rigid bodies' unconstrained step and system, the collision, the
        sweeps' first guess, the solve's loop decided on the device (:attr:`NodeSolve.loop`; run
        by ``NodeSolve.solve(..., batch=...)``) and what follows it (:meth:`_after_sweeps`), in
        the order the separate launches run them. Where it can be: off the CPU's arrays, the
        solver chosen (a step size's first step chooses it from the detection's contacts, so it
        runs as separate batches), one that decides on the device, the first guess carried from
        the last step (a state the user set starts from its own). None elsewhere."""
        solve = self._recorded[5]
        if not self.copies or not self._carried or solve is None or isinstance(solve, FactoredSolve) \
                or not solve.decides_on_device():
            return None
        key = (self._recorded, self._adhesion_replays, solve)
        if self._whole is not None and all(a is b for a, b in zip(self._whole[0], key)):
            return self._whole[1]
        dynamics, collision, _ = self._stages()
        assert isinstance(dynamics, LaunchBatch) and isinstance(collision, LaunchBatch)  # (self.copies)
        before = [self.rigid.before_launches()] if self.rigid is not None else []
        drive = [self._drive_nodes] if self.model.kinematic else []
        batch = LaunchBatch([*drive, *dynamics.replays, *before, *collision.replays, self._recorded[9][True],
                             *solve.loop.replays, *self._after_sweeps(solve).replays], self.device)
        self._whole = (key, batch)
        return batch

    def _solver(self, dt: float) -> NodeSolve | FactoredSolve:
        """The recorded sweeps for ``dt``: Jacobi or Gauss-Seidel, whichever needs less work per
        decade with this step's contacts (:func:`choose_sweeps`), chosen with its Chebyshev
        bounds on the first use; or the factored solve where it needs less work
        (:meth:`_factored`)."""
        if self._recorded[5] is None:
            if dt not in self._spectrum:
                bounds = spectrum(self.model, self.state)
                a, free = free_matrix(self.model, self.state)
                m, q = self.model, self.state.q.numpy()
                self._spectrum[dt] = choose_sweeps(m.row_start.numpy(), m.block_col.numpy(), a, free, bounds,
                                                   MAX_SWEEPS_PER_DECADE, movable_contacts(m, self.state),
                                                   SWEEP_PASSES, SPECTRUM_MARGIN,
                                                   (coarse_aggregates(m, q), q, m.mass.numpy()))
            choice = self._spectrum[dt]
            factored = self._factored(dt, choice)
            if choice.kind is None and factored is None:
                raise IllConditioned("node sweeps too slow: " + ", ".join(
                    f"{kind} {work:.0f} Jacobi sweeps of work per decade" for kind, work in choice.work.items()))
            self._recorded[5] = factored or NodeSolve(self.model, self.state, dt, choice.bounds,
                                          max_sweeps=self.scene.pgs_iterations, passes=choice.passes or SWEEP_PASSES,
                                          colours=choice.colours, omega=choice.omega, coarse=choice.coarse,
                                          parallel=self.scene._gpu_forms or None)
        return self._recorded[5]

    def _factored(self, dt: float, choice) -> FactoredSolve | None:
        """The factored solve (:mod:`softvr.contact.node_factored`) where the scene allows it
        (:func:`factored_eligible`, no adhesion) and its estimated work a contact step is less
        than the sweeps' (:func:`factored_work`, :func:`sweeps_step_work`); it is factored only
        where the sweeps need over :data:`MAX_SWEEPS_PER_DECADE` work a decade. A scene all
        sweeps decline (``choice.kind`` None) takes it rather than stepping per object (a
        sparse LU every step)."""
        sweeps = min(choice.work.values())
        # SciPy's factorization works on the host's arrays: CPU only (and not with the host copies
        # that stand in for a GPU's).
        if self.copies or self.adhesion is not None or not factored_eligible(self.model) \
                or sweeps <= MAX_SWEEPS_PER_DECADE:
            return None
        solve = FactoredSolve(self.model, self.state, dt, max_iterations=self.scene.pgs_iterations)
        return solve if factored_work(solve.fill, len(self.model.block_col)) < sweeps_step_work(sweeps) else None

    def _external_forces(self) -> None:
        s = self.scene
        if not (s.external or self._pushed):
            return
        self._external[:] = 0.0
        start = self.model.body_node_start
        for i, force in s.external.items():
            if 0 <= i < len(s.bodies) and self.fem[i]:
                f = np.asarray(force, float)
                nodes = int(start[i + 1] - start[i])
                if f.size != 3 * nodes or not np.isfinite(f).all():
                    raise InputError(f"external[{i}]", f"finite node forces of shape ({nodes}, 3) [N]",
                                     f"shape {f.shape}" if f.size != 3 * nodes else "NaN/inf")
                self._external[start[i]:start[i + 1]] = f.reshape(-1, 3)
        self._external_mirror.push()
        self._pushed = bool(s.external)

    def step(self, dt: float) -> tuple[LazySolution, dict]:
        """Advance the scene by ``dt`` [s]: the host's writes (:meth:`_begin`), the launches
        (:meth:`_launch`), the reads and the bodies' bookkeeping (:meth:`_finish`). Returns the
        lazily built solution and the stage times [ms] (``Scene.stage_ms``)."""
        t0 = time.perf_counter()
        driven = self._begin(dt)
        solve, sweeps, launched, t1, t2 = self._launch(dt)
        t3 = time.perf_counter()
        solution = self._finish(dt, solve, sweeps, launched, driven)
        t4 = time.perf_counter()
        return solution, dict(zip(("dynamics", "collision", "contact", "integrate"),
                                  (1e3 * (t1 - t0), 1e3 * (t2 - t1), 1e3 * (t3 - t2), 1e3 * (t4 - t3))))

    def _begin(self, dt: float) -> dict:
        """The host's side before a step's launches: last step's held solution and adhesion
        state let go of the arrays, what the user wrote copied in and pushed, the external
        forces, the drive (the driven bodies' velocities [6] by body, returned), the launches
        recorded for ``dt``."""
        held = self._issued()
        if held is not None:  # last step's solution is still held: it keeps its contacts
            held.detach()
        self._pulled.clear()  # (the step's reads come back after it)
        self._sync_in()
        for mirror in self._state_mirrors:  # before the drive, which writes the driven nodes' rows
            mirror.push()
        self._external_forces()
        driven = self._drive(dt)
        self._record(dt)
        if self.adhesion is not None:
            if self._adhesion_replays[0] != dt:
                self._adhesion_replays = (dt, self.adhesion.record(dt))
            self.adhesion.detach_issued()  # a held state copies its rows before evolve rewrites them
        return driven

    def _launch(self, dt: float) -> tuple[NodeSolve | FactoredSolve, int, bool, float, float]:
        """The step's launches and its solve: one batch where it can be (:meth:`_whole_step`),
        else the stages one after another (the solver chosen after the detection). Returns the
        solve, its sweeps, whether what follows it was launched with it (on the device's choice
        of sweep buffer), and the times [s] after the dynamics and after the collision."""
        tolerance = SWEEP_TOLERANCE if self.scene.pgs_tolerance is None else self.scene.pgs_tolerance
        whole = self._whole_step()
        if whole is not None:  # the step's launches as one batch: the first read waits for all of them
            solve = self._recorded[5]
            if self.rigid is not None:
                self.rigid.push_external()
            t1 = t2 = time.perf_counter()
            sweeps, _ = solve.solve(tolerance, batch=whole)
            return solve, sweeps, True, t1, t2
        dynamics, collision, _ = self._stages()
        if self.model.kinematic:
            self._drive_nodes()
        dynamics()
        if self.rigid is not None:  # off the CPU's arrays its divergence is read after the step
            self.rigid.before_sweeps(check=not self.copies)
        t1 = time.perf_counter()
        collision()
        t2 = time.perf_counter()
        solve = self._solver(dt)  # after the detection: the choice counts the contacts
        self._recorded[9][self._carried]()  # the sweeps' first guess
        self._carried = True
        # Off the CPU's arrays, a solve that decides on the device is launched with everything
        # after it (the launches for its buffer chosen on the device) before anything is read:
        # the step's first read waits for the whole step, none in its middle.
        if self.copies and not isinstance(solve, FactoredSolve) and solve.decides_on_device():
            sweeps, _ = solve.solve(tolerance, then=self._after_sweeps(solve))
            return solve, sweeps, True, t1, t2
        sweeps, _ = solve.solve(tolerance)
        if self.adhesion is not None:
            self._adhesion_replays[1][1][sweeps % 3]()
        return solve, sweeps, False, t1, t2

    def _finish(self, dt: float, solve, sweeps: int, launched: bool, driven: dict) -> LazySolution:
        """After the solve: the settling (unless ``launched`` with it), the checks, the states
        pulled, the rigid and driven bodies moved, the steps counted; the step's solution."""
        if not launched:
            self._stages()[2][sweeps % 3]()
        if self.adhesion is not None:
            self.scene.adhesion_state = self.adhesion.state()
        if self.rigid is not None and self.copies:
            self.rigid.check_before()
        self._check()
        pull_all(self._state_mirrors)
        if self.rigid is not None:
            if launched:
                self.rigid.after_sweeps(launched=True)
            else:
                self.rigid.integrate(sweeps % 3)
        for i, body in enumerate(self.scene.bodies):
            if self.fem[i]:
                body.step_count += 1
                body.last_cg_iterations = 0
            elif i in driven:
                body.integrate(driven[i], dt)
        snapshot = _NodeSnapshot(self, min(int(self._host("count")[0]), self.state.contacts.capacity),
                                 [self._views[i][1].copy() if self.fem[i] else driven[i] if i in driven
                                  else self.scene.bodies[i].v.copy() for i in range(len(self.fem))], sweeps,
                                 float(solve.stats.numpy()[1]))
        self._issued = weakref.ref(snapshot)
        return LazySolution(snapshot)

    def _host(self, name: str) -> np.ndarray:
        """Array ``name`` of those a step reads back on the host (:meth:`_hosts`)."""
        return self._hosts((name,))[0]

    def _hosts(self, names) -> list[np.ndarray]:
        """Arrays ``names`` of those a step reads back (:meth:`_contacts_out`, ``point_x``,
        ``diverged``) on the host: on the CPU views of their memory (Warp's ``numpy()`` costs a
        few us a call, and a step makes 20); elsewhere views of host copies, those of ``names``
        not yet read since the step copied back together with one wait (:func:`pull_all`; the
        contacts' fields their first ``count`` rows), so that a caller asking for the fields it
        needs at once waits once (the haptic tool's pushing normals, every step: six fields).
        The views are the step's until the next step reads again (:meth:`_NodeSnapshot.detach`
        copies out what a held one needs)."""
        if "count" not in self._pulled and any(n in _BY_CONTACT for n in names):
            self._hosts(("count",))  # how many rows of the others to copy
        missing = [n for n in names if n not in self._pulled]
        if missing:
            count = min(int(self._host_mirrors["count"].host[0]), self.state.contacts.capacity)
            pull_all([self._host_mirrors[n] for n in missing], [count if n in _BY_CONTACT else None for n in missing])
            self._pulled.update(missing)
        return [self._host_mirrors[n].host for n in names]

    def _contacts_out(self, n: int) -> dict:
        """The last step's ``n`` contacts as host arrays (those of :data:`_CONTACT_FIELDS` views of
        the stepper's), with ``movable``: whether an impulse can act on any node of the contact's
        stencil."""
        out = {name: array[:n] for name, array in zip(_CONTACT_FIELDS, self._hosts(
            _CONTACT_FIELDS + ("stencil_nodes", "stencil_count") + tuple(_RIGID_CONTACT_FIELDS if self.rigid else ())))}
        if self.rigid is not None:  # the primitives' keys, points and areas, from the rigid path's rows
            primitive = out["kind"] == 3
            if primitive.any():
                rows = np.where(primitive, out["point"], 0)
                out.update({name: self._host(name)[rows] for name in _RIGID_CONTACT_FIELDS})
                # The rigid path's area (a box corner's share of its face, a sphere's cap; thesis
                # 4.3.1), which the node arrays' own area holds only in a scene with adhesion.
                out["area"] = np.where(primitive, out.pop("rigid_area"), out["area"])
            else:  # every row reads the rigid path's row 0, as above, and keeps its own area
                out.update({name: np.repeat(self._host(name)[:1], n, axis=0) for name in _RIGID_CONTACT_FIELDS
                            if name != "rigid_area"})
        out["movable"] = self._movable(slice(n))
        return out

    def _movable(self, rows) -> np.ndarray:
        """Whether an impulse can act on any node of the stencil of the last step's contacts ``rows``."""
        nodes = self._host("stencil_nodes")[rows]
        # Unused stencil entries (-1) read the last node's flag, which ``used`` masks out.
        used = self._stencil_slots < self._host("stencil_count")[rows, None]
        return (used & self._free_nodes[nodes]).any(axis=1)

    def _check(self) -> None:
        """Stop with a report naming the body, node and step (SimulationError) if one diverged."""
        diverged = self._hosts(("diverged", "count"))[0]  # (the count with it: one wait)
        if diverged.any():
            i = int(np.flatnonzero(diverged)[0])
            b = int(np.searchsorted(self.model.body_node_start, i, side="right") - 1)
            body = self.scene.bodies[b]
            reason = NODE_DIVERGENCE_REASONS[int(diverged[i])]
            raise body._diverged(f"node {i - self.model.body_node_start[b]}: {reason}")
