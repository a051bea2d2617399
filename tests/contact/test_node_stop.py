"""The stop of the node sweeps (softvr.contact.node_jacobi.NodeSolve): the nodes' largest change
(a geometric-tail estimate, FEM nodes) and the contacts' residual of eq. 5.5 in m/s (normal
velocity error; the natural residual of every contact row: complementarity, the friction disc's
stick or slip, adhesion's bounds). A rigid body's nodes are not in the change: their update is
exact for the sweep's impulses, so their error is their contacts'.

Held to physics: every step a rigid box lands and turns on a soft block, dry and glued, solves
the MLCP of eq. 5.5 (each body's A v = b + J^T lambda, the contacts' complementarity and
Coulomb's stick / slip); a box spinning flat on a plane slows by the friction torque's analytic
rate and then sticks.

Tolerances: the sweeps stop within SWEEP_TOLERANCE = 1e-5 m/s (tests/sim/test_node_arrays.py
allows 3x, VELOCITY_TOL); the spin's is derived in its test.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.contact import Adhesion
from softvr.dynamics import RigidBody, RigidPoints
from softvr.model.shapes import box_surface

from tests.contact.test_node_adhesion import _add_block
from tests.sim.test_node_rigid import VELOCITY_TOL, _generalized, _system, contact_velocities

G = 9.81  # [m/s^2]
MU = 0.5
GLUE = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)


def _box(scene, half, position, glue=None, **kwargs) -> RigidBody:
    """A rigid box of half extents ``half`` [m] (density 800 kg/m^3), its corners as collision
    points and its 12 outward triangles as its surface."""
    box = RigidBody.box(2 * half, 800.0, position=position, **kwargs)
    verts, tris = box_surface(2 * half, 1)
    scene.add_body(box, collision_points=RigidPoints(box, verts - half), collision_triangles=tris, adhesion=glue)
    return box


def _landing_box(glue):
    """A rigid box (corners and faces), tilted, landing on a soft block that stands on the plane
    (test_node_rigid's scene; the block of test_node_adhesion), every surface glued with
    ``glue`` (None: dry)."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=MU, contact_margin=0.002)
    block = _add_block(scene, 0.2, 3, (-0.1, -0.1, 0.0005), glue)
    scene.add_plane(Plane(friction=MU), adhesion=glue)
    box = _box(scene, np.array([0.04, 0.03, 0.02]), (0.01, -0.005, 0.2005 + 0.03), glue,
               orientation=(np.cos(0.05), np.sin(0.05), 0.0, 0.0))
    return scene, block, box


def _check_step(scene, systems, solution, bonded, dt):
    """Eq. 5.5 for every body and contact of a step: A v = b + J^T lambda per body within the
    tolerance times A's largest row sum; n . J v >= -gap / dt, with equality where the contact
    pushes; lambda_n >= 0 unless the contact is bonded (key in ``bonded``); where it pushes and
    is not bonded, Coulomb: friction inside the disc, and either sticking (inside: no tangential
    velocity) or sliding (on the rim: the tangential velocity against the friction). Returns
    (contacts with a rigid and an FEM side, pulling contacts)."""
    bodies = scene.bodies
    v = [_generalized(b, b.v) for b in bodies]
    impulse = [np.zeros_like(x) for x in v]
    weight = max(b.mass if type(b) is RigidBody else b.mass.sum() for b in bodies) * G * dt
    mixed = pulling = 0
    for contacts, lam, frames in zip(solution.contacts, solution.impulses, solution.frames):
        rel, is_mixed = contact_velocities(bodies, v, impulse, contacts, lam, frames)
        mixed += is_mixed * len(lam)
        glued = np.isin(contacts.ids, list(bonded))
        pulling += int((lam[:, 0] < 0).sum())
        assert (lam[glued, 0] < 0).sum() == (lam[:, 0] < 0).sum()  # only bonds pull
        vn = np.einsum("ci,ci->c", rel, frames[:, 0])
        assert (vn >= -contacts.gap / dt - VELOCITY_TOL).all()
        pushing = lam[:, 0] > 1e-6 * weight
        np.testing.assert_allclose(vn[pushing], -contacts.gap[pushing] / dt, atol=VELOCITY_TOL)
        dry = pushing & ~glued
        friction = np.hypot(lam[dry, 1], lam[dry, 2])
        assert (friction <= MU * lam[dry, 0] * (1 + 1e-9) + 1e-12).all()
        slip = np.einsum("cij,cj->ci", frames[dry][:, 1:], rel[dry])  # tangential velocity (t1, t2)
        sticking = friction < MU * lam[dry, 0] * (1 - 1e-6)
        np.testing.assert_allclose(slip[sticking], 0.0, atol=VELOCITY_TOL)
        rim = lam[dry][~sticking, 1:] / np.maximum(friction[~sticking], 1e-300)[:, None]
        along = np.einsum("ci,ci->c", slip[~sticking], rim)
        assert (along <= VELOCITY_TOL).all()  # friction never pushes the slip on
        across = slip[~sticking] - along[:, None] * rim
        np.testing.assert_allclose(across, 0.0, atol=VELOCITY_TOL)
    for (a, b, free), x, f in zip(systems, v, impulse):
        residual = a @ x.ravel() - b - f.ravel()
        assert np.abs(residual[free]).max() <= VELOCITY_TOL * np.abs(a).sum(axis=1).max()
    return mixed, pulling


@pytest.mark.parametrize("glue", [None, GLUE], ids=["dry", "glued"])
def test_a_box_landing_on_a_block_dry_and_glued_solves_the_mlcp_of_eq_5_5_each_step(glue):
    """The box lands on a corner and an edge, turns (the lever arms act) and settles; glued, its
    contacts bond and some pull. Every step whose sweeps end before the cap holds the MLCP,
    rigid sides included; only the landing's may reach the cap (3 dry, 4 glued, on the old stop too:
    their linearized vertex-triangle constraints conflict, as in test_node_rigid.py)."""
    scene, block, box = _landing_box(glue)
    dt = 1.0 / 60.0
    mixed = capped = pulling = 0
    for _ in range(40):
        systems = [_system(b, dt, scene.gravity) for b in scene.bodies]
        bonded = {k for k, beta in scene.adhesion_state.intensity.items() if beta > 0}
        solution = scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper"
        if solution.iterations >= scene.pgs_iterations:
            capped += 1
            continue
        m, p = _check_step(scene, systems, solution, bonded, dt)
        mixed += m > 0
        pulling += p
    assert capped <= 4
    assert mixed >= 30
    assert (pulling > 0) == (glue is not None)


def test_a_box_spinning_flat_on_a_plane_slows_at_the_friction_torque_and_then_sticks():
    """A box (half extents a, b, c; its 4 bottom corners at r = sqrt(a^2 + b^2) from the spin
    axis) spins about z on a plane: while its corners slide, friction mu lambda_n on each, against
    the corner's velocity, is a pure torque mu r sum(lambda_n) = mu r m g dt a step (the box
    neither lifts nor tilts), and I_zz = m r^2 / 3, so implicit Euler slows it by exactly
    dw = 3 mu g dt / r a step; once dw exceeds what spin is left, static friction stops it in
    that step and holds it. A fixed FEM block stands apart (the node arrays need an FEM body).

    Tolerance: each step's contact velocities are within VELOCITY_TOL of eq. 5.5's, so the
    normal impulses' sum is within m VELOCITY_TOL of m g dt, and the friction torque within
    mu r m VELOCITY_TOL: the spin gains at most 3 mu VELOCITY_TOL / r of error a step, n times
    that after n steps; stuck, the corners' speed w r is within VELOCITY_TOL of 0."""
    mu, dt, steps, w0 = 0.2, 0.005, 30, 4.0
    half = np.array([0.1, 0.06, 0.02])
    r = float(np.hypot(half[0], half[1]))
    scene = Scene(gravity=(0.0, 0.0, -G), friction=mu)
    _add_block(scene, 0.1, 2, (5.0, 0.0, 0.0), None, clamped=True)
    scene.add_plane(Plane(friction=mu))
    box = _box(scene, half, (0.0, 0.0, half[2]))
    box.v[5] = w0
    slow = 3.0 * mu * G * dt / r  # [rad/s] a step
    assert 5 < w0 / slow < steps - 5  # it slides, then sticks, within the run
    for n in range(1, steps + 1):
        scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper"
        expected = max(w0 - n * slow, 0.0)
        tol = n * 3.0 * mu * VELOCITY_TOL / r if expected > 0 else VELOCITY_TOL / r
        assert box.v[5] == pytest.approx(expected, abs=tol), n
        np.testing.assert_allclose(box.v[:5], 0.0, atol=VELOCITY_TOL / r)
