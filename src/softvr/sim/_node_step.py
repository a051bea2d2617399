"""The step of a scene of FEM bodies on planes, on whole-scene arrays (a fixed launch sequence):

    element terms + A, b of eq. 5.2 (node blocks)  ->  contacts, one launch
    ->  sweeps of eq. 5.6 (outer Jacobi with D_A = node blocks, inner PGS, Chebyshev), until
        the velocities stop changing  ->  warm starts carried  ->  integration

No factorization and no separate unconstrained solve: the sweeps solve ``A v = b + J^T lambda``
with the contacts' complementarity at once. The Chebyshev weights need bounds of the spectrum
of D_A^-1 A; they are computed (Lanczos) once per step size from the first step's ``A``, with
margins, and widened if a step's sweeps stop contracting.

The bodies keep working as the user-facing API: their ``q``, ``v`` and ``fixed_velocity`` are
views of the state arrays (a value the user assigns is copied in before the next step).
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from softvr.collision.contacts import ContactKind, Contacts, ContactSide, contact_keys, point_jacobian_blocks
from softvr.contact import ContactSolution
from softvr.contact.adhesion import AdhesionState
from softvr.contact.islands import contact_islands
from softvr.contact.node_jacobi import NodeSolve
from softvr.device import replayer
from softvr.dynamics.node_arrays import NODE_DIVERGENCE_REASONS, record_elements, record_integrate, record_system
from softvr.collision.node_detection import record_carry, record_node_detection
from softvr.errors import InputError
from softvr.sim._rigid_step import LazySolution, StepSnapshot
from softvr.sim.node_model import build_node_model

__all__ = ["NodeStepper"]

#: Safety factors on the Lanczos estimates of the spectrum of D_A^-1 A: an underestimated
#: radius makes the Chebyshev iteration diverge, an overestimated one only slows it.
SPECTRUM_MARGIN = (0.8, 1.02)
#: Velocity error [m/s] at which the sweeps stop (the per-object path's PGS tolerance).
SWEEP_TOLERANCE = 1e-5


def spectrum(model, state) -> tuple[float, float]:
    """Bounds (lo, hi) of the eigenvalues of D_A^-1 A over the free nodes, from this step's
    ``A`` (``state.blocks``): Lanczos on the similar symmetric L^-1 A L^-T (L L^T = D_A),
    with :data:`SPECTRUM_MARGIN`."""
    n = model.node_count
    if not (model.fixed.numpy() == 0).any():
        return 1.0, 1.0  # nothing to solve for: every node is driven
    blocks = state.blocks.numpy()
    a = sp.bsr_matrix((blocks, model.block_col.numpy(), model.row_start.numpy()), shape=(3 * n, 3 * n)).tocsr()
    free = np.repeat(model.fixed.numpy() == 0, 3)
    a = a[free][:, free]
    diag = blocks[np.flatnonzero(model.block_row.numpy() == model.block_col.numpy())]  # rows sorted: node order
    l_inv = np.linalg.inv(np.linalg.cholesky(diag))[model.fixed.numpy() == 0]
    k = len(l_inv)
    l_inv = sp.bsr_matrix((l_inv, np.arange(k), np.arange(k + 1)), shape=(3 * k, 3 * k)).tocsr()
    s = (l_inv @ a @ l_inv.T).tocsr()
    hi = float(spla.eigsh(s, k=1, which="LA", return_eigenvectors=False, tol=1e-3)[0])
    shifted = (hi * sp.identity(s.shape[0]) - s).tocsr()
    lo = hi - float(spla.eigsh(shifted, k=1, which="LA", return_eigenvectors=False, tol=1e-6)[0])
    return max(lo, 1e-6 * hi) * SPECTRUM_MARGIN[0], hi * SPECTRUM_MARGIN[1]


class _NodeSnapshot(StepSnapshot):
    """A node step's snapshot (:class:`StepSnapshot`), with the step's start positions for the
    contact points."""

    def __init__(self, stepper, contacts: dict, q0: np.ndarray, velocities: list, sweeps: int, residual: float):
        super().__init__(contacts, velocities, sweeps, residual)
        self._stepper, self._q0 = stepper, q0

    def sets(self) -> list[np.ndarray]:
        """Rows of each contact set, one per (body, plane) in the per-object path's order (body,
        then plane; points ascending); contacts whose stencil is all fixed nodes are left out."""
        if self._sets is None:
            s = self._stepper
            c = self.contacts
            body = np.searchsorted(s.model.body_point_start, c["point"], side="right") - 1
            movable = s.movable_point[c["point"]]
            order = np.lexsort((c["point"], c["plane"], body))
            order = order[movable[order]]
            pair = body[order] * (len(s.scene.planes) + 1) + c["plane"][order]
            cuts = np.flatnonzero(np.diff(pair)) + 1
            self._sets = [rows for rows in np.split(order, cuts) if len(rows)]
        return self._sets

    def _build(self) -> ContactSolution:
        s = self._stepper
        c = self.contacts
        sets = []
        for rows in self.sets():
            point = c["point"][rows]
            body = int(np.searchsorted(s.model.body_point_start, point[0], side="right") - 1)
            local = point - s.model.body_point_start[body]
            points = s.colliders[body].points
            blocks, jac = point_jacobian_blocks(points, local)
            nodes = points.nodes[local] + s.model.body_node_start[body]
            x = np.einsum("pk,pkx->px", points.weights[local], self._q0[nodes])
            normal = c["frame"][rows, 0]
            gap = c["gap"][rows]
            plane = int(c["plane"][rows[0]])
            sets.append(Contacts(ContactSide(body, blocks, jac), None, normal, gap, x, x - gap[:, None] * normal,
                                 contact_keys(ContactKind.POINT_PLANE, body, local, plane, 0), c["friction"][rows],
                                 np.zeros(len(rows))))
        islands = contact_islands(len(self.velocities), [(x.a.body, None) for x in sets])
        return ContactSolution(velocities=self.velocities, impulses=self.per_set("impulse"),
                               frames=self.per_set("frame"), iterations=self.sweeps, residual=self.residual,
                               islands=[sorted(i) for i in islands], contacts=sets,
                               gaps_after=self.per_set("gap_after"))


class NodeStepper:
    """Steps a scene of FEM bodies on planes (:func:`~softvr.sim.node_model_supported`) on its
    arrays; built from the scene's current state and warm starts."""

    def __init__(self, scene):
        self.scene = scene
        self.model, self.state = build_node_model(scene)
        self._settings = self._scene_settings()
        self.colliders = {c.body: c for c in scene._colliders}
        fixed = self.model.fixed.numpy()
        nodes = self.model.point_nodes.numpy()
        self.movable_point = ((nodes >= 0) & (fixed[np.maximum(nodes, 0)] == 0)).any(axis=1)
        self._bind_bodies()
        self._carry_in(scene._warm)
        self._recorded = None
        self._spectrum = {}

    def _scene_settings(self) -> tuple:
        s = self.scene
        return s._layout, float(s.contact_margin), tuple(len(b.q) for b in s.bodies)

    def still_valid(self) -> bool:
        """Whether the arrays still describe the scene."""
        return self._settings == self._scene_settings()

    def _bind_bodies(self) -> None:
        st = self.state
        self._q, self._v, self._fixed_v = st.q.numpy(), st.v.numpy(), st.fixed_velocity.numpy()
        self._external = st.external.numpy()
        self._diverged = st.diverged.numpy()
        self._count = st.contacts.count.numpy()
        self._mass = self.model.mass.numpy()
        self._fixed = self.model.fixed.numpy() != 0
        self._v_before = None  # velocities at the start of the last step [n, 3] [m/s]
        start = self.model.body_node_start
        self._views = [(self._q[a:b], self._v[a:b], self._fixed_v[a:b]) for a, b in zip(start[:-1], start[1:])]
        for body, (q, v, fv) in zip(self.scene.bodies, self._views):
            body.q, body.v, body.fixed_velocity = q, v, fv
        self._pushed = True

    def _sync_in(self) -> None:
        """Copy in any position or velocity the user assigned since the last step."""
        for body, views in zip(self.scene.bodies, self._views):
            for name, view in zip(("q", "v", "fixed_velocity"), views):
                value = getattr(body, name)
                if value is not view:
                    value = np.asarray(value, float)
                    if value.shape != view.shape:
                        raise InputError(f"{body.name}.{name}", f"an array of shape {view.shape}",
                                         f"shape {value.shape}")
                    view[:] = value
                    setattr(body, name, view)
                    self._v_before = None  # a new state: last step's change says nothing

    def _keys(self, points: np.ndarray, planes: np.ndarray) -> np.ndarray:
        """Contact keys of global points against planes (kind POINT_PLANE, as points_vs_plane)."""
        start = self.model.body_point_start
        body = np.searchsorted(start, points, side="right") - 1
        return contact_keys(ContactKind.POINT_PLANE, body, points - start[body], planes, 0)

    def _carry_in(self, warm: dict) -> None:
        """The per-object path's warm starts (world impulses by key) into the carried table."""
        p, s = self.model.point_count, len(self.scene.planes)
        if not warm or not p or not s:
            return
        points, planes = np.meshgrid(np.arange(p), np.arange(s), indexing="ij")
        keys = self._keys(points.ravel(), planes.ravel()).reshape(p, s)
        table = self.state.contacts.carried.numpy()
        for (i, j), key in np.ndenumerate(keys):
            if int(key) in warm:
                table[i, j] = warm[int(key)]

    def carried_out(self) -> tuple[AdhesionState, dict]:
        """The adhesion state (empty: these scenes have no adhesion) and the warm starts (world
        impulses by key) for the per-object path."""
        table = self.state.contacts.carried.numpy()
        i, j = np.nonzero(np.abs(table).sum(axis=2) > 0)
        return AdhesionState(), {int(k): table[a, b].copy() for k, a, b in zip(self._keys(i, j), i, j)}

    def _record(self, dt: float) -> None:
        s = self.scene
        key = (dt, tuple(s.gravity), s.pgs_iterations)
        if self._recorded is not None and self._recorded[0] == key:
            return
        m, st = self.model, self.state
        elements = record_elements(m, st)
        assemble, rhs = record_system(m, st, dt, s.gravity)
        detect = replayer(record_node_detection(m, st, dt, s.gravity))
        carry = replayer(record_carry(m, st))
        integrate = [replayer(record_integrate(m, st, dt, buf)) for buf in st.sweep_buffers]
        self._recorded = [key, elements, assemble, rhs, detect, None, carry, integrate]

    def _solver(self, dt: float) -> NodeSolve:
        """The recorded sweeps for ``dt`` (the Chebyshev bounds estimated on the first use)."""
        if self._recorded[5] is None:
            if dt not in self._spectrum:
                self._spectrum[dt] = spectrum(self.model, self.state)
            self._recorded[5] = NodeSolve(self.model, self.state, dt, self._spectrum[dt],
                                          max_sweeps=self.scene.pgs_iterations)
        return self._recorded[5]

    def _external_forces(self) -> None:
        s = self.scene
        if not (s.external or self._pushed):
            return
        self._external[:] = 0.0
        start = self.model.body_node_start
        for i, force in s.external.items():
            if 0 <= i < len(s.bodies):
                f = np.asarray(force, float)
                nodes = int(start[i + 1] - start[i])
                if f.size != 3 * nodes or not np.isfinite(f).all():
                    raise InputError(f"external[{i}]", f"finite node forces of shape ({nodes}, 3) [N]",
                                     f"shape {f.shape}" if f.size != 3 * nodes else "NaN/inf")
                self._external[start[i]:start[i + 1]] = f.reshape(-1, 3)
        self._pushed = bool(s.external)

    def step(self, dt: float) -> tuple[LazySolution, dict]:
        """Advance the scene by ``dt`` [s]; the lazily built solution and the stage times [ms]."""
        t0 = time.perf_counter()
        self._sync_in()
        self._external_forces()
        self._record(dt)
        _, elements, assemble, rhs, detect, _, carry, integrate = self._recorded
        q0 = self._q.copy()
        elements()
        assemble()
        rhs()
        solve = self._solver(dt)
        t1 = time.perf_counter()
        detect()
        t2 = time.perf_counter()
        # The sweeps start from last step's velocity change carried on (v + (v - v_before)), or
        # on a first step the explicit one (v + dt (g + f_ext / m)): a uniform change (gravity,
        # a push, a resting body's none) is Jacobi's slowest mode, and these guesses have it.
        buffers = self.state.sweep_buffers
        if self._v_before is None:
            start = self._v + dt * (np.asarray(self.scene.gravity, float) + self._external / self._mass[:, None])
        else:
            start = 2.0 * self._v - self._v_before
        self._v_before = self._v.copy()
        start[self._fixed] = self._fixed_v[self._fixed]
        buffers[0].numpy()[:] = start
        buffers[2].numpy()[:] = start
        sweeps, solved = solve.solve(SWEEP_TOLERANCE)
        carry()
        t3 = time.perf_counter()
        integrate[sweeps % 3]()
        self._check()
        for body in self.scene.bodies:
            body.step_count += 1
            body.last_cg_iterations = 0
        n = min(int(self._count[0]), self.state.contacts.capacity)
        c = self.state.contacts
        contacts = {name: getattr(c, name).numpy()[:n].copy()
                    for name in ("point", "plane", "frame", "gap", "friction", "impulse", "gap_after")}
        velocities = [v.copy() for _, v, _ in self._views]
        snapshot = _NodeSnapshot(self, contacts, q0, velocities, sweeps, float(solve.stats.numpy()[1]))
        t4 = time.perf_counter()
        return LazySolution(snapshot), dict(zip(("dynamics", "collision", "contact", "integrate"),
                                               (1e3 * (t1 - t0), 1e3 * (t2 - t1), 1e3 * (t3 - t2), 1e3 * (t4 - t3))))

    def _check(self) -> None:
        """Stop with a report naming the body, node and step (SimulationError) if one diverged."""
        if self._diverged.any():
            i = int(np.flatnonzero(self._diverged)[0])
            b = int(np.searchsorted(self.model.body_node_start, i, side="right") - 1)
            body = self.scene.bodies[b]
            reason = NODE_DIVERGENCE_REASONS[int(self._diverged[i])]
            raise body._diverged(f"node {i - self.model.body_node_start[b]}: {reason}")
