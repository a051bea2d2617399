"""Rigid bodies on whole-scene node arrays (softvr.sim.NodeModel with NodeRigid): a rigid body
is two nodes (linear and angular velocity) whose only blocks of A (thesis eq. 5.2) are m I and
I_w, in the same sweeps (eq. 5.6) as the FEM bodies it meets. Held to physics: statics (the
block carries m g; Hooke's law), the discrete free fall, Coulomb's friction angle and the MLCP
of eq. 5.5.

Tolerances come from the sweeps' stopping rule (SWEEP_TOLERANCE = 1e-5 m/s on the velocities,
estimated from a geometric tail: 3x allowed), as in test_node_arrays.py.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import FemBody, Material, RigidBody, RigidPoints
from softvr.scene import bundled, load_scene
from softvr.sim import node_model_supported
from softvr.sim._node_step import SWEEP_TOLERANCE

from tests.sim.test_node_couplings import sprung_block_scene
from tests.sim.test_node_surfaces import _add_with_surface, _block

G = 9.81
VELOCITY_TOL = 3 * SWEEP_TOLERANCE  # [m/s]
# A box's 8 corners (index 4 x + 2 y + z, each 0 / 1 for - / +) and its 12 outward triangles.
CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
FACES = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]


def _rigid_box(scene, half, density, position, primitive=False, surface=True, **kwargs):
    """A rigid box of half extents ``half`` [m]: its corners as collision points and its 12
    triangles as its surface, or (``primitive``) its box primitive."""
    half = np.asarray(half, float)
    box = RigidBody.box(2 * half, density, position=position, **kwargs)
    extra = {"collision_box": half} if primitive else {}
    if surface:
        extra.update(collision_points=RigidPoints(box, CORNERS * half), collision_triangles=FACES)
    scene.add_body(box, **extra)
    return box


def _system(body, dt, gravity):
    """(A, b) of eq. 5.2 for one body: an FEM body's step system; for a rigid body the blocks
    m I and I_w with b = A v_free, v_free the rigid path's unconstrained velocity (gyroscopic
    term included), as the node arrays hold it."""
    if type(body) is FemBody:
        system = body.step_system(dt, gravity)
        return system.matrix, system.rhs, ~system.prescribed
    a = np.zeros((6, 6))
    a[:3, :3] = body.mass * np.eye(3)
    a[3:, 3:] = body.inertia_world
    return a, a @ body.unconstrained_velocity(dt, gravity), np.ones(6, bool)


def _generalized(body, v):
    """A body's velocity as velocity blocks [k, bs] (FEM: nodes x 3; rigid: one block of 6)."""
    return np.asarray(v, float).reshape(len(body.q), 3) if type(body) is FemBody else np.reshape(v, (1, 6))


def contact_velocities(bodies, v, impulse, contacts, lam, frames):
    """One contact set's relative velocities ``J v`` [c, 3] [m/s] (world axes) from the body
    velocity blocks ``v``, with its impulses ``lam`` [c, 3] [N s] (contact frames ``frames``
    [c, 3, 3]) added into the bodies' ``impulse`` blocks as ``J^T lambda`` (side a takes
    +lambda, side b -lambda); also whether its sides are an FEM and a rigid body."""
    world = np.einsum("ci,cij->cj", lam, frames)
    rel = np.zeros_like(world)
    for side, sign in ((contacts.a, 1.0), (contacts.b, -1.0)):
        if side is None:
            continue
        rel += sign * np.einsum("ckij,ckj->ci", side.jac, v[side.body][side.blocks])
        np.add.at(impulse[side.body], side.blocks, sign * np.einsum("ckji,cj->cki", side.jac, world))
    mixed = contacts.b is not None and {type(bodies[contacts.a.body]), type(bodies[contacts.b.body])} == \
        {FemBody, RigidBody}
    return rel, mixed


def _check_mlcp(scene, systems, solution, dt, mu):
    """Eq. 5.5 for every body and contact of a step: A v = b + J^T lambda per body (side a
    takes +lambda, side b -lambda), lambda_n >= 0, n . J v >= -gap / dt with equality where the
    contact pushes, the friction in the disc |lambda_t| <= mu lambda_n. Returns the number of
    contacts whose sides are an FEM and a rigid body."""
    bodies = scene.bodies
    v = [_generalized(b, b.v) for b in bodies]
    impulse = [np.zeros_like(x) for x in v]
    mixed = 0
    weight = max(b.mass if type(b) is RigidBody else b.mass.sum() for b in bodies) * G * dt
    for contacts, lam, frames in zip(solution.contacts, solution.impulses, solution.frames):
        rel, is_mixed = contact_velocities(bodies, v, impulse, contacts, lam, frames)
        mixed += is_mixed * len(lam)
        vn = np.einsum("ci,ci->c", rel, contacts.normal)
        assert (lam[:, 0] >= 0).all()
        assert (vn >= -contacts.gap / dt - VELOCITY_TOL).all()
        pushing = lam[:, 0] > 1e-6 * weight
        np.testing.assert_allclose(vn[pushing], -contacts.gap[pushing] / dt, atol=VELOCITY_TOL)
        assert (np.hypot(lam[:, 1], lam[:, 2]) <= mu * lam[:, 0] * (1 + 1e-9) + 1e-12).all()
    for (a, b, free), body, x, f in zip(systems, bodies, v, impulse):
        residual = a @ x.ravel() - b - f.ravel()
        # The sweeps stop within VELOCITY_TOL of the fixed point: A's largest row sum times it.
        assert np.abs(residual[free]).max() <= VELOCITY_TOL * np.abs(a).sum(axis=1).max()
    return mixed


def _box_on_block(mu=0.5, edge_contacts=False):
    scene = Scene(gravity=(0.0, 0.0, -G), friction=mu, edge_contacts=edge_contacts)
    block = _block(3, 0.2, (0.0, 0.0, 0.1005), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2))
    _add_with_surface(scene, block)
    scene.add_plane(Plane(friction=mu))
    # Tilted a little, so its corners and edges land one after the other and it turns.
    box = _rigid_box(scene, (0.04, 0.03, 0.02), 800.0, (0.01, -0.005, 0.2005 + 0.03),
                     orientation=(np.cos(0.05), np.sin(0.05), 0.0, 0.0))
    return scene, block, box


@pytest.mark.parametrize("edge_contacts", [False, True])
def test_a_contact_step_with_rigid_sides_solves_the_mlcp_of_eq_5_5(edge_contacts):
    """A rigid box (corners and faces) lands and turns on a soft block: every step whose sweeps
    converge solves both bodies' MLCP together, the box's contacts weighted by their lever
    arms. (The step the box's edge lands on, at 5 rad/s, ends at the sweep cap 3.7e-5 m/s short:
    its linearized vertex-triangle constraints of both sides conflict, as the stacked blocks'
    rim contacts do in test_node_surfaces.py.)"""
    scene, block, box = _box_on_block(edge_contacts=edge_contacts)
    assert node_model_supported(scene)
    dt = 1.0 / 60.0
    mixed = capped = 0
    kinds = set()
    turned = 0.0
    for _ in range(40):
        systems = [_system(b, dt, scene.gravity) for b in scene.bodies]
        solution = scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper"
        turned = max(turned, float(np.abs(box.v[3:]).max()))
        if solution.iterations >= scene.pgs_iterations:
            capped += 1
            continue
        mixed += _check_mlcp(scene, systems, solution, dt, 0.5) > 0
        kinds |= {int(c.ids[0]) >> 60 for c in solution.contacts if c.b is not None}
    # Vertex-triangle contacts both ways (kind 3); with edge contacts on, the box's edges lie on
    # the block's flat top with both ends touching it, a patch the vertex-triangle contacts hold,
    # and make no contact (issue 16; test_node_edge_cover.py). Before: {3, 4} with edge contacts on.
    assert kinds == {3}
    assert capped <= 1
    assert mixed >= 30
    assert turned > 1.0  # the lever arms acted [rad/s]


def test_a_rigid_plate_on_a_block_carries_its_weight_and_compresses_it_by_hookes_law():
    """nu = 0, the bottom clamped, a rigid plate wider than the block resting on it: at rest
    the contact impulses sum to M g dt (the plate's equilibrium) and the block is uniformly
    strained by M g / (E A), which linear tets represent exactly, plus its own weight's
    rho g h^2 / (2 E) at the top (a bar under its weight; 4.9e-6 m at density 10 kg/m^3,
    allowed to be a tenth off: the tets' lumped masses are not uniform across a layer).
    nu = 0 leaves the top without lateral motion, so friction does no work at rest; it is
    there because a frictionless plate on springs is unstable (tilted, it slides to its low
    side, which tilts it more: it grew 2.5x per 0.2 s here)."""
    young, h, dt, density = 1e5, 0.1, 0.01, 10.0
    block = _block(2, h, (0.0, 0.0, h / 2), Material(young, 0.0, density, alpha=0.0, beta=1e-2),
                   fixed=lambda x: x[:, 2] < 1e-9, corotational=False)
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5)
    _add_with_surface(scene, block)
    half = np.array([0.1, 0.1, 0.01])  # wider than the block: its corners touch nothing
    plate = _rigid_box(scene, half, 5000.0, (0.0, 0.0, h + half[2] + 0.0005))
    assert node_model_supported(scene)
    for _ in range(200):
        solution = scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    weight = plate.mass * G
    force = sum(lam[:, 0].sum() for lam in solution.impulses) / dt
    # Equilibrium within the sweeps' velocity tolerance: M VELOCITY_TOL / dt [N].
    assert force == pytest.approx(weight, abs=plate.mass * VELOCITY_TOL / dt)
    own = density * G * h * h / (2 * young)
    delta = weight * h / (young * h * h) + own
    top = block.q[:, 2][block.rest[:, 2] > h - 1e-9]
    np.testing.assert_allclose(top, h - delta, atol=0.1 * own + VELOCITY_TOL * dt)
    np.testing.assert_allclose(plate.v, 0.0, atol=VELOCITY_TOL)


def test_a_rigid_box_falls_freely_then_rests_on_a_plane_among_fem_bodies():
    """Implicit Euler under gravity alone: v_n = -n g dt, z_n = z_0 - g dt^2 n (n + 1) / 2
    (exactly, while no contact acts); the box primitive then lands on the plane beside a soft
    cube and rests with its corners less than 1 mm below it."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5)
    cube = _block(2, 0.1, (0.3, 0.0, 0.0505), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2))
    _add_with_surface(scene, cube)
    scene.add_plane(Plane(friction=0.5))
    half = np.array([0.05, 0.04, 0.03])
    z0 = 0.3
    box = _rigid_box(scene, half, 500.0, (0.0, 0.0, z0), primitive=True, surface=False)
    assert node_model_supported(scene)
    dt = 0.01
    n = 0
    # Free while the lowest corner stays above the plane by more than the margin and a step's
    # travel (no contact is detected).
    while z0 - G * dt * dt * (n + 1) * (n + 2) / 2 - half[2] > scene.contact_margin + G * dt * (n + 2) * dt:
        scene.step(dt)
        n += 1
        assert type(scene._stepper).__name__ == "NodeStepper"
        assert box.position[2] == pytest.approx(z0 - G * dt * dt * n * (n + 1) / 2, abs=1e-12)
        np.testing.assert_allclose(box.v, [0, 0, -n * G * dt, 0, 0, 0], atol=1e-12)
    assert n > 10
    for _ in range(150):
        scene.step(dt)
    corners = box.position + CORNERS * half @ box.rotation.T
    assert corners[:, 2].min() > -1e-3
    np.testing.assert_allclose(box.v, 0.0, atol=1e-3)


@pytest.mark.parametrize("slope, slides", [(20.0, False), (35.0, True)])
def test_a_rigid_box_on_an_incline_sticks_below_the_friction_angle_and_slides_above(slope, slides):
    """Coulomb (mu = 0.5, friction angle 26.6 degrees): at 20 degrees the box stays; at 35 it
    slides down with a = g (sin theta - mu cos theta), here over 40 steps from rest. A fixed
    FEM block stands apart on the same arrays."""
    mu, dt, steps = 0.5, 0.005, 40
    theta = np.radians(slope)
    normal = np.array([-np.sin(theta), 0.0, np.cos(theta)])
    scene = Scene(gravity=(0.0, 0.0, -G), friction=mu)
    block = _block(2, 0.1, (5.0, 0.0, 0.0), Material(5e4, 0.3, 1000.0), fixed=lambda x: np.ones(len(x), bool))
    _add_with_surface(scene, block)
    scene.add_plane(Plane(normal=normal, friction=mu))
    half = np.array([0.05, 0.05, 0.02])
    # Resting on the incline: turned by theta about y, its centre half[2] above the plane.
    q = (np.cos(theta / 2), 0.0, -np.sin(theta / 2), 0.0)
    box = _rigid_box(scene, half, 500.0, tuple(half[2] * normal), primitive=True, surface=False, orientation=q)
    assert node_model_supported(scene)
    for _ in range(steps):
        scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    _check_incline(box, np.array([-np.cos(theta), 0.0, -np.sin(theta)]), normal, theta, mu, dt, steps, slides)


def _check_incline(box, down, normal, theta, mu, dt, steps, slides):
    """Coulomb on an incline of ``theta`` [rad] (unit ``down`` the slope, ``normal`` out of it)
    after ``steps`` of ``dt`` [s] from rest: the box slides at a = g (sin theta - mu cos theta)
    or (not ``slides``) stays, and does not move off the slope."""
    speed = float(box.v[:3] @ down)
    if slides:
        # Implicit Euler from rest: v_n = n a dt exactly once every contact slides.
        assert speed == pytest.approx(steps * G * (np.sin(theta) - mu * np.cos(theta)) * dt, rel=1e-3)
    else:
        assert abs(speed) < 1e-6
    assert abs(float(box.v[:3] @ normal)) < VELOCITY_TOL


def test_stacked_box_primitives_beside_a_soft_cube_solve_the_mlcp_and_carry_their_weights():
    """Two rigid box primitives stacked on the plane (box-box contacts: two rigid sides each)
    beside a soft cube: every step solves the MLCP of eq. 5.5, and at rest the box-box
    contacts carry the upper box's weight, the plane the lower's too (impulses / dt, within
    the masses times VELOCITY_TOL / dt)."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5)
    cube = _block(2, 0.1, (0.4, 0.0, 0.0505), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2))
    _add_with_surface(scene, cube)
    scene.add_plane(Plane(friction=0.5))
    half = np.array([0.05, 0.05, 0.03])
    lower = _rigid_box(scene, half, 500.0, (0.0, 0.0, half[2] + 0.001), primitive=True, surface=False)
    upper = _rigid_box(scene, 0.8 * half, 500.0, (0.005, 0.0, 2 * half[2] + 0.8 * half[2] + 0.003),
                       primitive=True, surface=False)
    assert node_model_supported(scene)
    dt = 0.01
    for _ in range(60):
        systems = [_system(b, dt, scene.gravity) for b in scene.bodies]
        solution = scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper"
        _check_mlcp(scene, systems, solution, dt, 0.5)
    force = {}
    for contacts, lam in zip(solution.contacts, solution.impulses):
        if contacts.a.body in (1, 2):
            key = "boxes" if contacts.b is not None else "plane"
            force[key] = force.get(key, 0.0) + lam[:, 0].sum() / dt
    tol = (lower.mass + upper.mass) * VELOCITY_TOL / dt
    assert force["boxes"] == pytest.approx(upper.mass * G, abs=tol)
    assert force["plane"] == pytest.approx((lower.mass + upper.mass) * G, abs=tol)


def test_a_rigid_box_on_a_sprung_block_is_carried_by_the_plane_and_the_springs():
    """Newton's first law at rest with rigid sides and couplings in the same sweeps: a rigid
    box rests on a block that stands on the plane and hangs from a fixed body by springs
    (test_node_couplings.py's scene). The box's contacts carry m_box g; the block's contacts
    (the plane's up, the box's down) plus the springs carry m_block g; each within the
    masses times VELOCITY_TOL / dt."""
    scene, block, index, link = sprung_block_scene()
    box = _rigid_box(scene, (0.03, 0.03, 0.01), 2000.0, (0.0, 0.0, 0.1 + 0.0105))
    assert node_model_supported(scene)
    dt = 0.01
    for _ in range(150):
        solution = scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    tol = (block.mass.sum() + box.mass) * VELOCITY_TOL / dt
    np.testing.assert_allclose(solution.force_on(scene.bodies.index(box), dt), [0.0, 0.0, box.mass * G], atol=tol)
    springs = link.forces().sum(axis=0)  # on side a, the block
    np.testing.assert_allclose(solution.force_on(index, dt) + springs, [0.0, 0.0, block.mass.sum() * G], atol=tol)


def test_bundled_scenes_with_rigid_and_fem_bodies_are_held_by_the_node_arrays():
    # The candies (rigid boxes and spheres with surfaces, soft candies, the Jell-O) are held.
    for name in ("candy.toml", "candy-adhesive.toml"):
        scene = load_scene(bundled(name)).scene
        assert any(type(b) is RigidBody for b in scene.bodies)
        # candy-adhesive's hand (a kinematic sphere that meets nothing) no longer keeps it off.
        assert node_model_supported(scene)
