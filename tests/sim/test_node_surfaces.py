"""Contacts between bodies on whole-scene node arrays (softvr.sim.NodeModel): FEM surfaces against
each other (vertex-triangle and edge-edge, thesis 5.1.2) and against kinematic bodies, whose
collision points are driven nodes. Held to the MLCP of eq. 5.5 and to Hooke's law.

Tolerances come from the sweeps' stopping rule (SWEEP_TOLERANCE = 1e-5 m/s on the velocities,
estimated from a geometric tail: 3x allowed), as in test_node_arrays.py.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import EmbeddedPoints, FemBody, KinematicBody, Material, RigidPoints
from softvr.scene import bundled, load_scene
from softvr.sim import node_model_supported
from softvr.sim._node_step import SWEEP_TOLERANCE
from softvr.volume import Volume, grid_tet_mesh
from softvr.volume.tetmesh import boundary_faces

G = 9.81
VELOCITY_TOL = 3 * SWEEP_TOLERANCE  # [m/s]


def _block(cells, size, center, material, fixed=None, corotational=True, name="block"):
    spacing = np.full(3, size / cells)
    corner = np.asarray(center, float) - size / 2
    nodes, tets = grid_tet_mesh(Volume(np.zeros((cells,) * 3, np.uint8), spacing=spacing,
                                       origin=spacing / 2 + corner), cells)
    return FemBody(nodes, tets, material, fixed=None if fixed is None else fixed(nodes), corotational=corotational,
                   name=name)


def _add_with_surface(scene, body):
    """The body's boundary nodes as collision points, its boundary faces as its surface."""
    faces = boundary_faces(body.tets)
    used = np.unique(faces)
    local = np.full(len(body.q), -1)
    local[used] = np.arange(len(used))
    scene.add_body(body, collision_points=EmbeddedPoints(body, used[:, None], np.ones((len(used), 1))),
                   collision_triangles=local[faces])


def _stack(edge_contacts):
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5, edge_contacts=edge_contacts)
    soft = Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2)
    lower = _block(3, 0.2, (0.0, 0.0, 0.1005), soft, name="lower")
    # Smaller and centred: its bottom face lies inside the lower block's top (an overhang makes
    # contacts at the rim whose linearized constraints conflict, so no step meets them all).
    upper = _block(2, 0.12, (0.0, 0.0, 0.262), soft, name="upper")
    for body in (lower, upper):
        _add_with_surface(scene, body)
    scene.add_plane(Plane(friction=0.5))
    return scene, [lower, upper]


def _side_velocity(side, velocities):
    """J v of one contact side [c, 3] [m/s] (3x3 blocks of an FEM body's nodes)."""
    return np.einsum("ckij,ckj->ci", side.jac, velocities[side.body][side.blocks])


@pytest.mark.parametrize("parallel", [False, True], ids=["one thread", "thread per contact"])
@pytest.mark.parametrize("edge_contacts", [False, True])
def test_two_bodies_in_contact_solve_the_mlcp_of_eq_5_5(edge_contacts, parallel):
    """Per body A v = b + J^T lambda (side a's impulse +, side b's -), and per contact
    lambda_n >= 0, n . (J_a v_a - J_b v_b) >= -gap / dt with equality where it pushes, friction
    in the disc: the sweeps solve the two bodies' MLCP together, with the contact step walked by
    one thread (the CPU's) or a thread per contact (a GPU's: Jacobi over the contacts on split
    masses, softvr.contact._node_parallel_kernels), whose contacts between the blocks share nodes."""
    scene, bodies = _stack(edge_contacts)
    scene._gpu_forms = parallel
    dt = 1.0 / 60.0
    kinds = set()
    checked = 0
    for step in range(45):
        systems = [b.step_system(dt, scene.gravity) for b in bodies]
        solution = scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper"
        assert scene._stepper._recorded[5].parallel == scene._gpu_forms  # (the option of conftest sets it)
        v = [b.v for b in bodies]
        impulse = [np.zeros((len(b.q), 3)) for b in bodies]
        between = 0
        for contacts, lam, frames in zip(solution.contacts, solution.impulses, solution.frames):
            world = np.einsum("ci,cij->cj", lam, frames)
            rel = _side_velocity(contacts.a, v)
            np.add.at(impulse[contacts.a.body], contacts.a.blocks, np.einsum("ckji,cj->cki", contacts.a.jac, world))
            if contacts.b is not None:
                rel = rel - _side_velocity(contacts.b, v)
                np.add.at(impulse[contacts.b.body], contacts.b.blocks,
                          -np.einsum("ckji,cj->cki", contacts.b.jac, world))
                between += len(lam)
                kinds.add(int(contacts.ids[0]) >> 60)
            vn = np.einsum("ci,ci->c", rel, contacts.normal)
            assert (lam[:, 0] >= 0).all()
            assert (vn >= -contacts.gap / dt - VELOCITY_TOL).all()
            pushing = lam[:, 0] > 1e-6 * bodies[1].mass.sum() * G * dt
            np.testing.assert_allclose(vn[pushing], -contacts.gap[pushing] / dt, atol=VELOCITY_TOL)
            assert (np.hypot(lam[:, 1], lam[:, 2]) <= 0.5 * lam[:, 0] * (1 + 1e-9) + 1e-12).all()
        for system, body, f in zip(systems, bodies, impulse):
            residual = system.matrix @ body.v.ravel() - system.rhs - f.ravel()
            free = ~system.prescribed
            assert np.abs(residual[free]).max() <= VELOCITY_TOL * np.abs(system.matrix).sum(axis=1).max()
        checked += between > 0
    assert checked >= 20
    # Vertex-triangle contacts (kind 3) either way: with edge contacts on, every edge pair of the
    # two faces lies on the patch the vertex-triangle contacts hold (both ends of one edge touch
    # the other block, which is flat across it) and makes no contact (issue 16: one contact per
    # touching feature pair; test_node_edge_cover.py). Before: {3, 4} with edge contacts on.
    assert kinds == {3}


def test_a_kinematic_plate_compresses_a_block_by_hookes_law():
    """nu = 0, the bottom clamped, no friction: pressing the top down by delta is a uniform
    strain delta / h, which linear tets represent exactly, so at rest the plate carries
    F = E A delta / h (the sum of the normal impulses over dt)."""
    young, h, delta, dt = 1e5, 0.1, 0.004, 0.01
    block = _block(2, h, (0.0, 0.0, h / 2), Material(young, 0.0, 1000.0, alpha=30.0, beta=0.0),
                   fixed=lambda x: x[:, 2] < 1e-9, corotational=False)
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.0)
    _add_with_surface(scene, block)
    half = np.array([0.1, 0.1, 0.01])  # wider than the block: its corners touch nothing
    start = h + half[2] + 0.0005

    def pose(t):
        return (0.0, 0.0, start - (delta + 0.0005) * min(t / 0.5, 1.0)), (1.0, 0.0, 0.0, 0.0)

    plate = KinematicBody(pose, name="plate")
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half
    # The box's 12 outward triangles over its corners (index = 4 x + 2 y + z, each 0 / 1).
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    scene.add_body(plate, collision_points=RigidPoints(plate, corners), collision_triangles=faces)
    assert node_model_supported(scene)
    for _ in range(250):
        solution = scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    force = sum(lam[:, 0].sum() for lam in solution.impulses) / dt
    assert force == pytest.approx(young * h * h * delta / h, rel=0.01)
    top = block.q[:, 2][block.rest[:, 2] > h - 1e-9]
    np.testing.assert_allclose(top, h - delta, atol=1e-5)


def test_bundled_scenes_take_the_arrays_where_the_sweeps_converge_fast():
    # The oranges (four soft bodies on a plane) step on the arrays; the head CT of the
    # palpation scene is too stiff for plain sweeps (54 Jacobi sweeps per decade, Gauss-Seidel
    # 60 sweeps of work) and takes them with the coarse correction over its aggregates (38).
    oranges = load_scene(bundled("oranges.toml")).scene
    oranges.step(0.005)
    assert type(oranges._stepper).__name__ == "NodeStepper"
    palpation = load_scene(bundled("palpation.toml")).scene
    assert node_model_supported(palpation)
    palpation.step(0.01)
    choice = palpation._stepper._spectrum[0.01]
    assert choice.coarse is not None and choice.coarse.whole == 0 and len(choice.coarse) > 10
    assert choice.work["coarse"] < min(choice.work["jacobi"], choice.work["gauss-seidel"])


def test_switching_edge_contacts_rebuilds_the_arrays():
    # Scene.edge_contacts is read when the arrays are built: turning it on must bring the edge
    # pairs (kind 4) in on the next step.
    scene, _ = _stack(False)
    for _ in range(30):
        solution = scene.step(1.0 / 60.0)
    assert {int(c.ids[0]) >> 60 for c in solution.contacts if c.b is not None} == {3}
    assert scene._stepper.model.edges.shape[0] == 0
    scene.edge_contacts = True
    solution = scene.step(1.0 / 60.0)
    # The arrays rebuilt with the surfaces' edges; the stack's edge pairs lie on the patch its
    # vertex-triangle contacts hold and make no contact (test_node_edge_cover.py; before: {3, 4}).
    assert scene._stepper.model.edges.shape[0] > 0
    assert {int(c.ids[0]) >> 60 for c in solution.contacts if c.b is not None} == {3}
