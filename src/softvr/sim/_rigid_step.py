"""The step of a rigid scene on whole-scene arrays: a fixed sequence of recorded launches.

    unconstrained velocities (eq. 5.2)  ->  contacts, one launch per pair kind
    ->  contact solve + adhesion (eqs. 5.5-5.6, 4.16, 4.3.3), one launch  ->  integration

The scene's body objects keep working as the user-facing API: their ``position``,
``orientation`` and ``v`` are views of the state arrays (a value the user assigns is copied
in before the next step), ``Scene.last_solution`` and ``Scene.adhesion_state`` read the
arrays when asked. Steps write their contacts into two buffers in turn (sharing what the
contacts carry over), so a step's solution can view its contacts until the step after next, and
copies them out only if it is still held then. :mod:`softvr.sim.frame_metrics` reads a frame's metrics (penetration of
drawn points below planes, energies) off the same arrays in one recorded launch.
"""

from __future__ import annotations

import dataclasses
import time
import weakref

import numpy as np

from softvr.collision.contact_buffer import ContactBuffer
from softvr.collision.contacts import Contacts, rigid_side
from softvr.collision.rigid_detection import record_detection
from softvr.contact import ContactSolution
from softvr.contact.adhesion import AdhesionState
from softvr.contact.islands import contact_islands
from softvr.contact.pgs import contact_force_on, pushing_normals
from softvr.contact.rigid_pgs import record_rigid_solve
from softvr.device import replayer
from softvr.dynamics import KinematicBody
from softvr.dynamics.rigid_arrays import DIVERGENCE_REASONS, record_integrate, record_unconstrained
from softvr.sim.model import build_rigid_model

__all__ = ["LazySolution", "RigidStepper", "StepSnapshot", "bind_views", "sync_views"]


def bind_views(bodies: list, position: np.ndarray, orientation: np.ndarray, velocity: np.ndarray) -> list[tuple]:
    """Make each body's ``position``, ``orientation`` and ``v`` a view of its row of the host
    arrays of a :class:`~softvr.sim.RigidState` over ``bodies`` (in order): ``body_position``
    [B, 3] [m], ``body_orientation`` [B, 4] and ``body_velocity`` [B, 6] [m/s, rad/s] (on the
    CPU their own memory, else a :class:`~softvr.device.HostMirror`'s copies); returns the views."""
    # One view per body and field, made once: a user's assignment rebinds the attribute,
    # which an identity test against these finds (``store[i]`` makes a new view each time).
    views = [(position[i], orientation[i], velocity[i]) for i in range(len(bodies))]
    for body, view in zip(bodies, views):
        body.position, body.orientation, body.v = view
    return views


def sync_views(bodies: list, views: list[tuple]) -> None:
    """Copy in any pose or velocity the user assigned to ``bodies`` since :func:`bind_views`."""
    for body, (position, orientation, v) in zip(bodies, views):
        if body.position is not position:
            position[:] = body.position
            body.position = position
        if body.orientation is not orientation:
            orientation[:] = body.orientation
            body.orientation = orientation
        if body.v is not v:
            v[:] = body.v
            body.v = v


class StepSnapshot:
    """One step's contacts (``contacts``: field name -> array over the step's contacts) and
    ``velocities``, copied out of the arrays (the rigid step's contacts: viewed in its buffer until
    a later step writes it again); the :class:`ContactSolution` built only when read.
    A path's snapshot says how its contacts group into sets (:meth:`sets`) and builds the sets'
    :class:`Contacts` (:meth:`_build`)."""

    def __init__(self, contacts: dict, velocities: list, sweeps: int, residual: float):
        self.contacts, self.velocities, self.sweeps, self.residual = contacts, velocities, sweeps, residual
        self._sets: list[np.ndarray] | None = None
        self._per_set: dict[str, list[np.ndarray]] = {}
        self._solution: ContactSolution | None = None

    def sets(self) -> list[np.ndarray]:
        raise NotImplementedError

    def _build(self) -> ContactSolution:
        raise NotImplementedError

    def per_set(self, name: str) -> list[np.ndarray]:
        """The contact field ``name`` split by :meth:`sets` (the solution's ``impulses``,
        ``frames``, ``gaps_after`` need no Jacobians: an interactive loop reads only them)."""
        if name not in self._per_set:
            self._per_set[name] = [self.contacts[name][rows] for rows in self.sets()]
        return self._per_set[name]

    def set_bodies(self) -> list[tuple[int, int | None]]:
        """(side a's body, side b's body or None for a static) of each of :meth:`sets`; a path
        that can read them from its arrays answers without building the sets."""
        return self.solution().set_bodies()

    def pushing_normals(self, body: int) -> np.ndarray:
        """:meth:`ContactSolution.pushing_normals` (a path that can pick one body's contacts
        from its arrays answers without splitting them into sets)."""
        return pushing_normals(self.set_bodies(), self.per_set("impulse"), self.per_set("frame"), body)

    def contact_counts(self) -> tuple[int, int]:
        """(contacts, active contacts: normal impulse > 0) over the solution's sets."""
        impulses = self.per_set("impulse")
        return sum(len(i) for i in impulses), sum(int((i[:, 0] > 0).sum()) for i in impulses)

    def solution(self) -> ContactSolution:
        if self._solution is None:
            self._solution = self._build()
        return self._solution


class _Snapshot(StepSnapshot):
    """A rigid step's snapshot; also what :class:`ArrayAdhesionState` reads. Its ``contacts`` are
    views of the step's contact buffer (:meth:`ContactBuffer.views`, ``count`` rows) until
    :meth:`detach` copies them out, before a later step writes that buffer again."""

    def __init__(self, views: dict, count: int, velocities: list, sweeps: int, residual: float, moves: np.ndarray):
        self._views: dict | None = views
        self._count = count
        self._own: dict | None = None
        super().__init__(None, velocities, sweeps, residual)  # type: ignore[arg-type]  # contacts: read from views
        # [n + 1] bool: which bodies move (inverse mass > 0), False last for body -1 (a static):
        # to leave out contacts no impulse can act on.
        self._moves = moves

    @property
    def contacts(self) -> dict:
        if self._own is None:
            assert self._views is not None
            self._own = {name: view[:self._count] for name, view in self._views.items()}
        return self._own

    @contacts.setter
    def contacts(self, value) -> None:
        self._own = value

    def _field(self, name: str) -> np.ndarray:
        """``contacts[name]`` without making the other fields' views."""
        if self._own is not None or self._views is None:
            return self.contacts[name]
        return self._views[name][:self._count]

    def detach(self) -> None:
        """Copy the contacts out of the buffer, which the step after next writes again."""
        if self._views is not None:
            self._own = {name: view[:self._count].copy() for name, view in self._views.items()}
            self._views = None

    def sets(self) -> list[np.ndarray]:
        """Row indices of each contact set: one per (kind, body a, body b or static), in the
        order the sets first appear; contacts between two immovable sides are left out, as the
        per-object path (Scene._movable) does."""
        if self._sets is None:
            c = self.contacts
            movable = np.flatnonzero(self._movable())
            # A key's top 24 bits are (kind, body a, body b or the static's index): the set. A
            # dict keeps first-appearance order at ~1 us per contact (np.unique and a split cost
            # 3x that on the box stack's 20 contacts).
            pair = (c["key"][movable].view(np.uint64) >> np.uint64(40)).tolist()
            rows: dict[int, list] = {}
            for row, key in zip(movable.tolist(), pair):
                rows.setdefault(key, []).append(row)
            self._sets = [np.array(r) for r in rows.values()]
        return self._sets

    def set_bodies(self) -> list[tuple[int, int | None]]:
        first = [rows[0] for rows in self.sets()]
        a, b = self._field("body_a")[first].tolist(), self._field("body_b")[first].tolist()
        return [(x, None if y < 0 else y) for x, y in zip(a, b)]

    def _movable(self) -> np.ndarray:
        """[contacts] bool: the contacts with a movable side (those :meth:`sets` holds)."""
        return self._moves[self._field("body_a")] | self._moves[self._field("body_b")]

    def contact_counts(self) -> tuple[int, int]:
        """(contacts, active contacts) of :meth:`sets` from a mask, without splitting them."""
        if self._sets is not None:
            return super().contact_counts()
        movable = self._movable()
        return int(np.count_nonzero(movable)), int(np.count_nonzero(movable & (self._field("impulse")[:, 0] > 0)))

    def _build(self) -> ContactSolution:
        c = self.contacts
        sets = []
        for rows in self.sets():
            a, b = int(c["body_a"][rows[0]]), int(c["body_b"][rows[0]])
            side_b = None if b < 0 else rigid_side(b, c["offset_b"][rows])
            sets.append(Contacts(rigid_side(a, c["offset_a"][rows]), side_b,
                                 c["normal"][rows], c["gap"][rows], c["point_a"][rows], c["point_b"][rows],
                                 c["key"][rows], c["friction"][rows], c["area"][rows]))
        islands = contact_islands(len(self.velocities), [(s.a.body, None if s.b is None else s.b.body) for s in sets])
        return ContactSolution(velocities=self.velocities, impulses=self.per_set("impulse"),
                               frames=self.per_set("frame"), iterations=self.sweeps, residual=self.residual,
                               islands=[sorted(i) for i in islands], contacts=sets,
                               gaps_after=self.per_set("gap_after"))


class LazySolution:
    """The :class:`ContactSolution` of a step on arrays (rigid or node), built on first use (most steps
    of an interactive loop never read it); ``iterations`` (PGS sweeps), ``residual`` [m/s],
    ``velocities``, ``impulses``, ``frames`` and ``gaps_after`` without building its contact
    sets' Jacobians."""

    def __init__(self, snapshot: StepSnapshot):
        self._snapshot = snapshot
        self.iterations, self.residual = snapshot.sweeps, snapshot.residual
        self.velocities = snapshot.velocities

    @property
    def impulses(self) -> list:
        return self._snapshot.per_set("impulse")

    @property
    def frames(self) -> list:
        return self._snapshot.per_set("frame")

    @property
    def gaps_after(self) -> list:
        return self._snapshot.per_set("gap_after")

    def contact_counts(self) -> tuple[int, int]:
        """(contacts, active contacts: normal impulse > 0) of :attr:`impulses`, the sets not split
        where the path can count them whole."""
        return self._snapshot.contact_counts()

    def set_bodies(self) -> list[tuple[int, int | None]]:
        """:meth:`ContactSolution.set_bodies`, read from the step's arrays (a haptic tool and
        a force sensor need only these, the impulses and the frames: not the sets' Jacobians)."""
        return self._snapshot.set_bodies()

    def force_on(self, body: int, dt: float) -> np.ndarray:
        """:meth:`ContactSolution.force_on`, without building the contact sets."""
        return contact_force_on(self, body, dt)

    def pushing_normals(self, body: int) -> np.ndarray:
        """:meth:`ContactSolution.pushing_normals`, without building the contact sets."""
        return self._snapshot.pushing_normals(body)

    def __getattr__(self, name):
        return getattr(self._snapshot.solution(), name)


class ArrayAdhesionState(AdhesionState):
    """:class:`AdhesionState` of a rigid scene: the intensities and slips of the last step's
    contacts, read from its arrays."""

    def __init__(self, snapshot: _Snapshot | None = None):
        self._snapshot = snapshot

    @property
    def intensity(self) -> dict:  # type: ignore[override]  # read from the arrays; the per-object state assigns it
        if self._snapshot is None:
            return {}
        c = self._snapshot.contacts
        tracked = c["intensity"] >= 0
        return dict(zip(c["key"][tracked].tolist(), c["intensity"][tracked].tolist()))

    @property
    def slip(self) -> dict:  # type: ignore[override]  # read from the arrays; the per-object state assigns it
        if self._snapshot is None:
            return {}
        c = self._snapshot.contacts
        bonded = np.any(c["slip"] != 0.0, axis=1)
        return dict(zip(c["key"][bonded].tolist(), c["slip"][bonded]))


class RigidStepper:
    """Steps a rigid :class:`~softvr.sim.Scene` (:func:`~softvr.sim.rigid_model_supported`) on
    its arrays; built from the scene's current state, warm starts and adhesion."""

    def __init__(self, scene):
        self.scene = scene
        self.model, self.state = build_rigid_model(scene)
        # The steps' two contact buffers in turn: the state's, and one of its own rows sharing
        # what the contacts carry over (warm starts, intensities, slips).
        c = self.state.contacts
        carried = {f.name: getattr(c, f.name) for f in dataclasses.fields(c) if f.name.startswith("carried_")}
        other = dataclasses.replace(ContactBuffer.allocate(c.capacity, self.model.device), **carried)
        self._states = (self.state, dataclasses.replace(self.state, contacts=other))
        self._turn = 0  # the buffer the next step writes
        self._issued: list = [None, None]  # per buffer: a weak reference to the snapshot viewing it
        self._settings = self._scene_settings()
        self._bind_bodies()
        self._carry_in(scene.adhesion_state, scene._warm)
        self._recorded = None
        self._external = self.state.external.numpy()

    def _scene_settings(self) -> tuple:
        s = self.scene
        # Scene._layout counts the scene's changes (bodies, statics, couplings, filters).
        return s._layout, float(s.friction), float(s.contact_margin)

    def still_valid(self) -> bool:
        """Whether the arrays still describe the scene (settings baked into them unchanged)."""
        return self._settings == self._scene_settings()

    def _bind_bodies(self) -> None:
        self._position = self.state.body_position.numpy()
        self._orientation = self.state.body_orientation.numpy()
        self._velocity = self.state.body_velocity.numpy()
        self._free = self.state.free_velocity.numpy()
        self._diverged = self.state.diverged.numpy()
        self._clean = bytes(self._diverged.nbytes)  # no body diverged (a bytes test: 0.2 vs 1.5 us for any())
        self._buffers = [(st.contacts.views(), st.contacts.count.numpy()) for st in self._states]
        self._moves = np.append(self.model.body_inv_mass.numpy() > 0, False)  # [n + 1], body -1 static
        self._pushed = True
        self._views = bind_views(self.scene.bodies, self._position, self._orientation, self._velocity)
        # Kinematic bodies are rows of infinite mass (inverse mass 0, as fixed ones) moving at
        # their script's velocity: the contact solve reads it as their side's velocity.
        self._kinematic = {i for i, b in enumerate(self.scene.bodies) if isinstance(b, KinematicBody)}

    def _sync_in(self) -> None:
        """Copy in any pose or velocity the user assigned since the last step."""
        sync_views(self.scene.bodies, self._views)

    def _carry_in(self, adhesion: AdhesionState, warm: dict) -> None:
        """What the per-object path left (warm starts, intensities, slips), as the carried arrays."""
        c = self.state.contacts
        keys = np.array(sorted(set(warm) | set(adhesion.intensity)), np.int64)[: c.capacity]
        n = len(keys)
        c.carried_count.numpy()[0] = n
        # Ascending as signed int64 is not ascending as the kernel's uint64 bits (kind 8 sets the
        # top bit): sort the bits.
        bits = np.sort(keys.view(np.uint64))
        keys = bits.view(np.int64).tolist()
        c.carried_key.numpy()[:n] = bits
        c.carried_impulse.numpy()[:n] = [warm.get(k, (0.0, 0.0, 0.0)) for k in keys] or np.zeros((0, 3))
        c.carried_intensity.numpy()[:n] = [adhesion.intensity.get(k, -1.0) for k in keys]
        c.carried_slip.numpy()[:n] = [adhesion.slip.get(k, (0.0, 0.0, 0.0)) for k in keys] or np.zeros((0, 3))

    def carried_out(self) -> tuple[AdhesionState, dict]:
        """The adhesion state and warm starts (dictionaries by key) for the per-object path."""
        c = self.state.contacts
        n = int(c.carried_count.numpy()[0])
        keys = c.carried_key.numpy()[:n].view(np.int64).tolist()
        state = AdhesionState()
        beta, slip, impulse = c.carried_intensity.numpy()[:n], c.carried_slip.numpy()[:n], c.carried_impulse.numpy()[:n]
        state.intensity = {k: float(b) for k, b in zip(keys, beta) if b >= 0}
        state.slip = {k: s.copy() for k, s in zip(keys, slip) if np.any(s != 0)}
        return state, {k: v.copy() for k, v in zip(keys, impulse)}

    def _record(self, dt: float) -> None:
        s = self.scene
        if self._recorded is not None and self._recorded[0][0] == dt and self._recorded[0][1] is s.gravity \
                and self._recorded[0][2:] == (s.pgs_iterations, s.pgs_tolerance):
            return
        key = (dt, s.gravity, s.pgs_iterations, s.pgs_tolerance)
        turns = []
        for state in self._states:  # per contact buffer: its unconstrained (which empties it), detection, solve
            solve = record_rigid_solve(self.model, state, dt, max_sweeps=s.pgs_iterations,
                                       **({} if s.pgs_tolerance is None else {"tolerance": s.pgs_tolerance}))
            turns.append((replayer(record_unconstrained(self.model, state, dt, s.gravity)),
                          record_detection(self.model, state, dt), solve, replayer(solve.launch), solve.stats.numpy()))
        self._recorded = (key, turns, replayer(record_integrate(self.model, self.state, dt)))

    def step(self, dt: float) -> tuple[LazySolution, dict]:
        """Advance the scene by ``dt`` [s]; the lazily built solution and the stage times [ms]."""
        s = self.scene
        t0 = time.perf_counter()
        self._sync_in()
        self._record(dt)
        turn = self._turn
        held = self._issued[turn]() if self._issued[turn] is not None else None
        if held is not None:  # the solution of the step before last is still held: it keeps its contacts
            held.detach()
        _, turns, integrate = self._recorded
        unconstrained, detection, _, solve, stats = turns[turn]
        views, count = self._buffers[turn]
        if s.external or self._pushed:
            self._external[:] = 0.0
            for body, force in s.external.items():
                if 0 <= body < len(s.bodies):  # as the per-object path: other keys name no body
                    self._external[body] = s.bodies[body]._check_external(force)
            self._pushed = bool(s.external)
        unconstrained()
        for i in self._kinematic:
            self._free[i] = s.bodies[i].unconstrained_velocity(dt, s.gravity, s.external.get(i))
        self._check()
        t1 = time.perf_counter()
        detection.launch()
        t2 = time.perf_counter()
        solve()
        t3 = time.perf_counter()
        integrate()
        self._check()
        for i, body in enumerate(s.bodies):
            if i in self._kinematic:  # the script's pose at t + dt exactly, copied into the views
                body.integrate(self._free[i], dt)
                sync_views([body], [self._views[i]])
            else:
                body.step_count += 1
        snapshot = _Snapshot(views, min(int(count[0]), self.model.contact_capacity), list(self._velocity.copy()),
                             int(stats[0]), float(stats[1]), self._moves)
        self._issued[turn] = weakref.ref(snapshot)
        self._turn = 1 - turn
        s.adhesion_state = ArrayAdhesionState(snapshot)
        t4 = time.perf_counter()
        return LazySolution(snapshot), dict(zip(("dynamics", "collision", "contact", "integrate"),
                                               (1e3 * (t1 - t0), 1e3 * (t2 - t1), 1e3 * (t3 - t2), 1e3 * (t4 - t3))))

    def _check(self) -> None:
        """Stop with a report naming the body and the step (SimulationError) if one diverged."""
        if self._diverged.tobytes() != self._clean:
            i = int(np.flatnonzero(self._diverged)[0])
            body = self.scene.bodies[i]
            raise body._diverged(DIVERGENCE_REASONS[int(self._diverged[i])])

