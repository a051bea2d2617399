"""Rigid bodies on the whole-scene node arrays (:class:`~softvr.sim.NodeModel`).

A rigid body is two nodes of the arrays, its linear velocity and its world angular velocity.
Their only blocks of the step matrix ``A`` of thesis eq. 5.2 are the diagonal ones (``m I``
and the world inertia ``I_w``): the rigid path's unconstrained step (gravity, external force
and torque, the gyroscopic term) gives their right-hand side, so eq. 5.6's outer Jacobi with
``D_A`` the node blocks is exact on them and the sweeps only move them by the contacts'
impulses. A contact's Jacobian holds up to two rigid sides: the linear node in its stencil
with the point's weight, the angular node with the lever arm
(:mod:`softvr.collision.node_rigid_detection`). Rigid collision points and surfaces meet planes
and the FEM bodies' surfaces as the FEM points do; box and sphere primitives meet planes and
each other through the rigid path's detection; the bodies move by the rigid path's integration
(quaternions): both run on a :class:`~softvr.sim.RigidModel` of the rigid bodies alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import warp as wp

from softvr.device import HostMirror, in_order, pull_all, record_copy, replayer
from softvr.dynamics import RigidBody
from softvr.dynamics.node_rigid import record_rigid_system, record_rigid_velocity
from softvr.dynamics.rigid_arrays import DIVERGENCE_REASONS, record_integrate, record_unconstrained
from softvr.sim._rigid_step import bind_views, sync_views
from softvr.sim.model import RigidModel, RigidState, build_rigid_model

__all__ = ["NodeRigid", "RigidNodes", "build_node_rigid", "rigid_bodies"]


@dataclass
class NodeRigid:
    """The rigid bodies of a :class:`~softvr.sim.NodeModel` (``R`` bodies, ``p`` collision
    points in all, ``pr`` of them on rigid bodies).

    Attributes
    ----------
    bodies : list of int
        Scene index of each rigid body (host).
    body_scene : wp.array(int32) [R]
        The same on the device.
    linear_node, angular_node : wp.array(int32) [R]
        Each body's two nodes (its first and second).
    model : RigidModel; state : RigidState
        The rigid path's arrays over these bodies alone (bodies numbered 0..R-1), with their
        box and sphere primitives and the scene's planes and no collision points: its
        unconstrained step, primitive detection and integration run on them.
    point_index, point_rigid : wp.array(int32) [pr]
        Global collision point and its rigid body (0..R-1) of each rigid collision point.
    point_local : wp.array(vec3d) [pr] [m]
        Its body-frame position.
    point_angular : wp.array(int32) [p]
        The angular node of each collision point's body (-1: not a rigid body).
    point_lever : wp.array(vec3d) [p] [m]
        World offset of each rigid collision point from its body's centre at the step's start.
    """

    bodies: list
    body_scene: wp.array
    linear_node: wp.array
    angular_node: wp.array
    model: RigidModel
    state: RigidState
    point_index: wp.array
    point_rigid: wp.array
    point_local: wp.array
    point_angular: wp.array
    point_lever: wp.array


def rigid_bodies(scene) -> list[int]:
    """Scene indices of the bodies that are rigid nodes of the arrays (``RigidBody``)."""
    return [i for i, b in enumerate(scene.bodies) if type(b) is RigidBody]


class _RigidPart:
    """The rigid bodies of a scene as the scene :func:`~softvr.sim.build_rigid_model` reads:
    their primitives, the planes, the filters and margins, no collision points (the node
    arrays place and detect those) and no surfaces."""

    def __init__(self, scene, bodies: list[int]):
        index = {b: r for r, b in enumerate(bodies)}
        self._scene, self._index = scene, bodies
        self.bodies = [scene.bodies[b] for b in bodies]
        self.planes, self.friction = scene.planes, scene.friction
        self._colliders: list = []
        self._surfaces: list = []
        self._sphere_bodies = [(index[i], r) for i, r in scene._sphere_bodies if i in index]
        self._box_bodies = [(index[i], h) for i, h in scene._box_bodies if i in index]
        self._adhesion = {key: value for key, value in scene._adhesion.items() if key[0] == "static"}
        self._adhesion.update({("body", r): scene._adhesion[("body", b)] for r, b in enumerate(bodies)})

    def _scene_key(self, key: tuple) -> tuple:
        return ("body", self._index[key[1]]) if key[0] == "body" else key

    def collision_enabled(self, a: int, b: int) -> bool:
        return self._scene.collision_enabled(self._index[a], self._index[b])

    def _pair_margin(self, a: tuple, b: tuple) -> float:
        return self._scene._pair_margin(self._scene_key(a), self._scene_key(b))


def build_node_rigid(scene, node_start: np.ndarray, point_start: np.ndarray, device: str) -> NodeRigid | None:
    """The rigid part of a scene's node arrays (None without rigid bodies); ``node_start`` and
    ``point_start`` [bodies + 1] number the scene's nodes and collision points."""
    bodies = rigid_bodies(scene)
    if not bodies:
        return None
    model, state = build_rigid_model(_RigidPart(scene, bodies), device)
    index = {b: r for r, b in enumerate(bodies)}
    p = int(point_start[-1])
    point_index, point_rigid, point_local = [], [], []
    point_angular = np.full(max(p, 1), -1)
    for c in scene._colliders:
        if c.body in index:
            rows = np.arange(point_start[c.body], point_start[c.body + 1])
            point_index.append(rows)
            point_rigid.append(np.full(len(rows), index[c.body]))
            point_local.append(c.points.local)
            point_angular[rows] = node_start[c.body] + 1
    starts = np.asarray([node_start[b] for b in bodies])

    def i32(values):
        return wp.array(np.concatenate([np.zeros(0, np.int32)] + [np.asarray(v, np.int32) for v in values]),
                        dtype=wp.int32, device=device)

    return NodeRigid(bodies=bodies, body_scene=i32([bodies]), linear_node=i32([starts]), angular_node=i32([starts + 1]),
                     model=model, state=state, point_index=i32(point_index), point_rigid=i32(point_rigid),
                     point_local=wp.array(np.concatenate([np.zeros((0, 3))] + point_local), dtype=wp.vec3d,
                                          device=device),
                     point_angular=i32([point_angular]), point_lever=wp.zeros(max(p, 1), dtype=wp.vec3d, device=device))


class RigidNodes:
    """The rigid bodies' share of a node step (:class:`softvr.sim._node_step.NodeStepper`):
    the bodies' ``position``, ``orientation`` and ``v`` are views of ``rigid.state``; before the
    sweeps the rigid path's unconstrained step and the nodes' ``D_A^-1``, ``b``; after them the
    rigid path's integration of the solved node velocities."""

    def __init__(self, scene, rigid: NodeRigid, copies: bool = False):
        self.scene, self.rigid = scene, rigid
        self.bodies = [scene.bodies[b] for b in rigid.bodies]
        st = rigid.state
        # The bodies' poses and velocities, the external forces and the divergence flags on the
        # host: the arrays' memory on the CPU, copies elsewhere (``copies``: also on the CPU).
        self._poses = [HostMirror(a, copies) for a in (st.body_position, st.body_orientation, st.body_velocity)]
        self._views = bind_views(self.bodies, *(m.host for m in self._poses))
        self._external = HostMirror(st.external, copies)
        self._diverged = HostMirror(st.diverged, copies)
        # The divergence flags as the unconstrained step left them (before_sweeps(check=False):
        # read with the rest after the step, so that no read waits in its middle).
        self._diverged_before = HostMirror(wp.zeros_like(st.diverged), copies)
        self._recorded: tuple = ()

    def sync_in(self) -> None:
        """Copy in any pose or velocity the user assigned since the last step (or wrote into
        the bodies' arrays), up to the device."""
        sync_views(self.bodies, self._views)
        for mirror in self._poses:
            mirror.push()

    def record(self, state, dt: float, gravity) -> None:
        """Record the launches of a step of ``dt`` [s] under ``gravity`` [3] [m/s^2]; ``state``
        the :class:`~softvr.sim.NodeState`."""
        r = self.rigid
        self._recorded = (replayer(record_unconstrained(r.model, r.state, dt, gravity)),
                          record_rigid_system(r, state), [record_rigid_velocity(r, buf) for buf in state.sweep_buffers],
                          replayer(record_integrate(r.model, r.state, dt)),
                          record_copy(self._diverged_before.array, r.state.diverged))

    def push_external(self) -> None:
        """``Scene.external``'s forces and torques on the rigid bodies up to the device, for the
        unconstrained step after it (:meth:`before_sweeps`, :meth:`before_launches`)."""
        external = self._external.host
        external[:] = 0.0
        for r, b in enumerate(self.rigid.bodies):
            if b in self.scene.external:
                external[r] = self.bodies[r]._check_external(self.scene.external[b])
        self._external.push()

    def before_sweeps(self, check: bool = True) -> None:
        """The unconstrained velocities (eq. 5.2, with ``Scene.external``'s forces and torques)
        and the nodes' ``D_A^-1`` and ``b``; run after the FEM nodes' right-hand side. A body
        that diverged in it stops the step here (:meth:`check`), or, without ``check``, when
        :meth:`check_before` reads its flags after the step (the integration keeps a flagged
        body where it was)."""
        self.push_external()
        if check:
            unconstrained, system, _, _, _ = self._recorded
            unconstrained()
            self.check()
            system()
        else:
            self.before_launches()()

    def before_launches(self) -> Callable[[], None]:
        """:meth:`before_sweeps` without ``check`` as one replay, after :meth:`push_external`:
        the unconstrained step, its divergence flags kept for :meth:`check_before` (a launch),
        the nodes' system; nothing read back, so that it can sit in a step's batch."""
        unconstrained, system, _, _, keep = self._recorded
        return in_order(unconstrained, keep, system)

    def integrate(self, buffer: int) -> None:
        """Move the bodies by the velocities the sweeps solved (``state.sweep_buffers[buffer]``)."""
        _, _, velocity, _, _ = self._recorded
        velocity[buffer]()
        self.after_sweeps()

    def integrate_launches(self, buffer_flags: list) -> Callable[[], None]:
        """:meth:`integrate`'s launches for the buffer whose flag of ``buffer_flags`` [3] (int32
        arrays of one element: :attr:`NodeSolve.buffer_flags`) is set on the device, each as a
        ``wp.capture_if``, then the integration: nothing read back (:meth:`after_sweeps` with
        ``launched``)."""
        _, _, velocity, integrate, _ = self._recorded

        def run() -> None:
            for flag, launch in zip(buffer_flags, velocity):
                wp.capture_if(flag, on_true=launch)
            integrate()
        return run

    def after_sweeps(self, launched: bool = False) -> None:
        """The integration (unless ``launched`` already), the divergence check, the poses
        pulled to the host, the step counted."""
        if not launched:
            self._recorded[3]()
        self.check()
        pull_all(self._poses)
        for body in self.bodies:
            body.step_count += 1

    def check_before(self) -> None:
        """:meth:`check` on the flags the unconstrained step left (``before_sweeps(check=False)``)."""
        self._raise_diverged(self._diverged_before)

    def check(self) -> None:
        """Stop with a report naming the body and the step (SimulationError) if one diverged."""
        self._raise_diverged(self._diverged)

    def _raise_diverged(self, flags: HostMirror) -> None:
        flags.pull()
        diverged = flags.host
        if diverged.any():
            r = int(np.flatnonzero(diverged)[0])
            raise self.bodies[r]._diverged(DIVERGENCE_REASONS[int(diverged[r])])
