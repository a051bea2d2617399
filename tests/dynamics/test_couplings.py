"""Couplings and coupling islands (thesis 5.3.2, eq. 5.4) against statics, rigid-body dynamics
and an independent graph library.

Truths: SciPy's connected components for island detection; the coupling's generalized forces
through the point entities' own J^T F (a different path from the assembled island terms);
two rigid boxes tied at three points accelerate like one rigid body of their summed mass and
inertia (backward Euler of a constant load, exact in closed form), the springs' compliance
making an error that shrinks like 1/k; a soft block hanging from a fixed carrier by springs
carries its weight in them (statics: k sum(stretch) = m g); islands solved apart equal one
solve of all of them (the union of block-diagonal systems).
"""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components as scipy_components

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import (Coupling, CouplingIsland, EmbeddedPoints, FemBody, FixedBody, Material, RigidBody,
                             RigidPoints, connected_components, coupling_islands)
from softvr.errors import InputError
from softvr.volume import Volume, grid_tet_mesh

NO_GRAVITY = (0.0, 0.0, 0.0)


def box_mesh(size, cells, origin=(0.0, 0.0, 0.0)):
    size, cells = np.asarray(size, float), np.asarray(cells)
    spacing = size / cells
    nodes, tets = grid_tet_mesh(Volume(np.zeros(tuple(cells), np.uint8), spacing=spacing, origin=spacing / 2),
                                tuple(cells))
    return nodes + origin, tets


def node_points(body, mask):
    idx = np.flatnonzero(mask)
    return EmbeddedPoints(body, idx[:, None], np.ones((len(idx), 1)))


# ----------------------------------------------------------------------------- island detection
@pytest.mark.parametrize("count, pairs, expected", [
    (5, [(0, 1), (1, 2), (2, 3), (3, 4)], [[0, 1, 2, 3, 4]]),  # chain
    (5, [(0, 1), (0, 2), (0, 3)], [[0, 1, 2, 3], [4]]),  # star and a loner
    (6, [(4, 5), (1, 0), (2, 3)], [[0, 1], [2, 3], [4, 5]]),  # pairs, in any order
    (3, [], [[0], [1], [2]]),  # nothing coupled
    (4, [(0, 1), (1, 0), (2, 2)], [[0, 1], [2], [3]]),  # repeated and self pairs
])
def test_islands_of_hand_made_graphs(count, pairs, expected):
    assert connected_components(count, pairs) == expected


def test_islands_match_scipy_on_random_graphs():
    rng = np.random.default_rng(7)
    for _ in range(50):
        n = int(rng.integers(1, 40))
        pairs = [tuple(map(int, rng.integers(0, n, 2))) for _ in range(int(rng.integers(0, n)))]
        ours = connected_components(n, pairs)
        graph = sp.coo_matrix((np.ones(len(pairs)), ([a for a, _ in pairs], [b for _, b in pairs])), shape=(n, n))
        count, labels = scipy_components(graph, directed=False)
        theirs = sorted(sorted(np.flatnonzero(labels == k).tolist()) for k in range(count))
        assert ours == theirs


def test_coupling_islands_name_foreign_bodies():
    a, b, c = (RigidBody.sphere(0.1, 1000.0, name=n) for n in "abc")
    link = Coupling(RigidPoints(a, [[0.0, 0.0, 0.0]]), RigidPoints(c, [[0.0, 0.0, 0.0]]), 1e3, name="a-c")
    assert coupling_islands([a, b, c], [link]) == [[0, 2], [1]]
    with pytest.raises(InputError, match="a-c.*'c' is not in it"):
        coupling_islands([a, b], [link])


# ----------------------------------------------------------------------------- coupling terms
def test_coupling_terms_are_the_springs_forces_and_their_jacobian():
    """b's share is dt times the generalized spring forces, J^T F (computed by the point
    entities); A's share is dt^2 k D^T D + dt c D^T D, and with c = 0 the force is linear in the
    node positions of two FEM bodies, so its exact Jacobian is -k D^T D: checked by finite
    differences of J^T F."""
    nodes, tets = box_mesh((0.1, 0.1, 0.1), (1, 1, 1))
    a = FemBody(nodes, tets, Material(1e5, 0.3, 1000.0), name="a")
    b = FemBody(nodes + [0.1, 0.0, 0.0], tets, Material(1e5, 0.3, 1000.0), name="b")
    b.q[:] += np.random.default_rng(1).normal(0.0, 0.003, b.q.shape)  # stretched springs
    face_a, face_b = np.isclose(a.q[:, 0], 0.1), np.isclose(b.rest[:, 0], 0.1)
    k, dt = 2e3, 0.01
    link = Coupling(node_points(a, face_a), node_points(b, face_b), k)
    offsets = {id(a): 0, id(b): a.velocity_size}
    size = a.velocity_size + b.velocity_size
    matrix, rhs = link.step_terms(offsets, size, dt)
    f = link.forces()
    expected = np.concatenate([link.a.generalized_forces(f).ravel(), link.b.generalized_forces(-f).ravel()])
    np.testing.assert_allclose(rhs, dt * expected, atol=1e-12)

    def generalized(qa, qb):
        a.q, b.q = qa, qb
        g = link.forces()
        return np.concatenate([link.a.generalized_forces(g).ravel(), link.b.generalized_forces(-g).ravel()])

    q0 = np.concatenate([a.q.ravel(), b.q.ravel()])
    jac = np.zeros((size, size))
    h = 1e-6
    for i in range(size):
        up, down = q0.copy(), q0.copy()
        up[i] += h
        down[i] -= h
        n = a.velocity_size
        jac[:, i] = (generalized(up[:n].reshape(-1, 3), up[n:].reshape(-1, 3))
                     - generalized(down[:n].reshape(-1, 3), down[n:].reshape(-1, 3))) / (2 * h)
    np.testing.assert_allclose(matrix.toarray(), -dt * dt * jac, atol=1e-9)


# ----------------------------------------------------------------------------- rigid bodies tied as one
def _tied_boxes(k):
    a = RigidBody.box((0.2, 0.1, 0.1), 500.0, position=(0.0, 0.0, 0.0), name="a")
    b = RigidBody.box((0.1, 0.1, 0.1), 800.0, position=(0.15, 0.0, 0.0), name="b")
    joint = np.array([[0.1, 0.03, -0.03], [0.1, -0.03, -0.03], [0.1, 0.0, 0.04]])  # on the shared face
    scene = Scene(gravity=NO_GRAVITY)
    scene.add_body(a)
    scene.add_body(b)
    scene.add_coupling(Coupling(RigidPoints.from_world(a, joint), RigidPoints.from_world(b, joint), k))
    return scene, a, b


@pytest.mark.parametrize("load", ["force", "torque"])
def test_rigid_bodies_tied_at_three_points_move_as_one_as_k_grows(load):
    """A constant force along the line of centres (or torque about it, a principal axis of
    both boxes) on box a alone. One rigid body of the summed mass m (inertia I_xx) under
    backward Euler moves exactly as x_n = a dt^2 n (n + 1) / 2, omega_n = alpha dt n with
    a = F / m, alpha = tau / I_xx; box b must follow it, the lag being the springs' stretch
    ~ F m_b / (m 3 k): the error falls like 1/k (each 100x stiffer: >= 30x smaller) and is
    below 1e-6 of the travel at k = 1e9 N/m. (The torque spins them up to 6.7 rad/s: 0.013 rad
    per step, so holding J for a step costs nothing visible.)"""
    dt, steps = 0.002, 200
    push = 5.0 if load == "force" else 0.05
    errors = []
    for k in (1e5, 1e7, 1e9):
        scene, a, b = _tied_boxes(k)
        scene.external[0] = np.array([push, 0, 0, 0, 0, 0]) if load == "force" else np.array([0, 0, 0, push, 0, 0])
        for _ in range(steps):
            scene.step(dt)
        n = steps
        if load == "force":
            acc = push / (a.mass + b.mass)
            travel = acc * dt * dt * n * (n + 1) / 2
            errors.append(max(abs(b.position[0] - 0.15 - travel), abs(a.position[0] - travel)) / travel)
        else:
            ixx = a.inertia_body[0, 0] + b.inertia_body[0, 0]
            omega = push / ixx * dt * n
            errors.append(max(abs(b.v[3] - omega), abs(a.v[3] - omega)) / omega)
            # The three joint points are not symmetric about x: the springs' stretch under the
            # spin-up tilts b a little (relative 2e-7 at k = 1e5, less when stiffer).
            np.testing.assert_allclose(b.v[4:], 0.0, atol=1e-5 * omega)
    assert errors[0] > 30 * errors[1] > 900 * errors[2]
    assert errors[2] < 1e-6


# ----------------------------------------------------------------------------- statics of a hanging soft block
def test_soft_block_hanging_by_springs_carries_its_weight_in_them():
    """A 10 cm FEM block tied at its top nodes to a fixed carrier: at rest the springs hold the
    weight, k sum(stretch_z) = m g (Newton's third law on the block), and the net spring force
    has no horizontal part. Damped, it settles within 2 s (kinetic energy < 1e-10 J)."""
    nodes, tets = box_mesh((0.1, 0.1, 0.1), (2, 2, 2))
    block = FemBody(nodes, tets, Material(5e4, 0.3, 1000.0, alpha=10.0, beta=0.01), name="block")
    carrier = FixedBody(name="carrier")
    top = np.isclose(nodes[:, 2], 0.1)
    k = 2e3
    link = Coupling(node_points(block, top), RigidPoints.from_world(carrier, nodes[top]), k, name="hook")
    # The coupling island's exact solves (sparse LU): on the node arrays the sweeps stop at
    # 1e-5 m/s, a stretch of ~5e-8 m per step, 10x this balance's tolerance
    # (tests/sim/test_node_couplings.py holds the arrays to statics at theirs).
    scene = Scene(node_arrays=False)
    scene.add_body(block)
    scene.add_body(carrier)
    scene.add_coupling(link)
    for _ in range(400):
        scene.step(0.005)
    weight = block.mass.sum() * 9.81
    pull = -k * link.stretch().sum(axis=0)  # spring force on the block, summed
    np.testing.assert_allclose(pull, [0.0, 0.0, weight], atol=1e-6 * weight)
    assert block.kinetic_energy() < 1e-10
    assert carrier.position.tolist() == [0.0, 0.0, 0.0]


# ----------------------------------------------------------------------------- islands apart = one solve
def _bone_and_muscle(x, rng=None):
    """A rigid 'bone' box with a soft 'muscle' block tied on top by its bottom nodes."""
    nodes, tets = box_mesh((0.1, 0.1, 0.1), (2, 2, 2))
    bone = RigidBody.box((0.1, 0.1, 0.1), 1200.0, position=(x, 0.0, 0.05), name=f"bone at {x}")
    muscle = FemBody(nodes + [x - 0.05, -0.05, 0.1], tets, Material(3e4, 0.35, 1000.0, alpha=2.0, beta=0.01),
                     name=f"muscle at {x}")
    if rng is not None:
        muscle.v[:] = rng.normal(0.0, 0.1, muscle.v.shape)
        bone.v[:] = rng.normal(0.0, 0.5, 6)
    bottom = np.isclose(muscle.q[:, 2], 0.1)
    link = Coupling(node_points(muscle, bottom), RigidPoints.from_world(bone, muscle.q[bottom]), 5e3, damping=2.0,
                    name=f"insertion at {x}")
    return bone, muscle, link


def test_islands_solved_apart_equal_one_solve_of_all():
    """Two bone + muscle pairs: two islands, each one system; the same bodies as one island
    (block diagonal over the pairs) give the same velocities to round-off."""
    rng = np.random.default_rng(3)
    (b0, m0, c0), (b1, m1, c1) = _bone_and_muscle(0.0, rng), _bone_and_muscle(0.3, rng)
    bodies, couplings = [b0, m0, b1, m1], [c0, c1]
    assert coupling_islands(bodies, couplings) == [[0, 1], [2, 3]]
    apart = [CouplingIsland([b0, m0], [c0]), CouplingIsland([b1, m1], [c1])]
    together = CouplingIsland(bodies, couplings)
    dt, g = 0.005, (0.0, 0.0, -9.81)
    v_apart = np.concatenate([island.unconstrained_velocity(dt, g).ravel() for island in apart])
    v_together = together.unconstrained_velocity(dt, g).ravel()
    np.testing.assert_allclose(v_apart, v_together, rtol=0, atol=1e-12 * np.abs(v_together).max())
    # And both solve A v = b: the residual of the assembled system is at round-off.
    a, b, prescribed, _ = together.step_system(dt, g)
    assert not prescribed.any()
    assert np.abs(a @ v_together - b).max() < 1e-9 * np.abs(b).max()


def test_a_coupled_pair_rests_on_the_ground_carrying_its_weight():
    """Contacts on a coupling island: a bone with a muscle tied on top comes to rest on the
    ground; the ground carries both weights (the contact forces on the bone, the only member
    touching it) and the couplings keep the muscle on the bone (stretch = its weight / (k n))."""
    from softvr.model.shapes import box_surface

    bone, muscle, link = _bone_and_muscle(0.0)
    verts, tris = box_surface((0.1, 0.1, 0.1), 2)
    scene = Scene(friction=0.8)
    scene.add_body(bone, collision_points=RigidPoints(bone, verts - 0.05), collision_triangles=tris)
    scene.add_body(muscle)
    scene.add_coupling(link)
    scene.add_plane(Plane(friction=0.8))
    for _ in range(300):
        solution = scene.step(0.005)
    assert len(scene.solve_units()[0]) == 1  # one unit: the island
    weight = (bone.mass + muscle.mass.sum()) * 9.81
    np.testing.assert_allclose(solution.force_on(0, 0.005), [0.0, 0.0, weight], atol=2e-3 * weight)
    assert bone.position[2] > 0.05 - 1e-3
    sag = muscle.mass.sum() * 9.81 / (link.stiffness * len(link))
    np.testing.assert_allclose(link.stretch()[:, 2].mean(), -sag, rtol=0.02)


def test_bad_couplings_are_clear_errors():
    a, b = RigidBody.sphere(0.1, 1000.0, name="a"), RigidBody.sphere(0.1, 1000.0, name="b")
    one, two = RigidPoints(a, [[0.0, 0.0, 0.0]]), RigidPoints(b, [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    with pytest.raises(InputError, match="as many points as side a"):
        Coupling(one, two, 1e3)
    with pytest.raises(InputError, match="stiffness"):
        Coupling(one, RigidPoints(b, [[0.0, 0.0, 0.0]]), -1.0)
    with pytest.raises(InputError, match="another body"):
        Coupling(one, RigidPoints(a, [[0.1, 0.0, 0.0]]), 1e3)
    scene = Scene()
    scene.add_body(a)
    with pytest.raises(InputError, match="'b' is not in it"):
        scene.add_coupling(Coupling(one, RigidPoints(b, [[0.0, 0.0, 0.0]]), 1e3))


def test_parts_tied_to_a_fixed_bone_are_separate_islands():
    """A fixed bone couples nothing (its motion is prescribed): two muscles tied to it are two
    islands, each carrying the bone as a guest; the bone is stepped once per step, and each
    muscle hangs as it would alone (the same nodes as a scene with only that muscle)."""
    bone = FixedBody(name="scapula")
    nodes, tets = box_mesh((0.05, 0.05, 0.05), (2, 2, 2))

    def muscle(x):
        m = FemBody(nodes + [x, 0.0, -0.05], tets, Material(2e4, 0.3, 1000.0, alpha=5.0), name=f"muscle {x}")
        top = np.isclose(m.q[:, 2], 0.0)
        return m, Coupling(node_points(m, top), RigidPoints.from_world(bone, m.q[top]), 3e3, name=f"origin {x}")

    (m0, c0), (m1, c1) = muscle(0.0), muscle(0.1)
    scene = Scene()
    for body in (bone, m0, m1):
        scene.add_body(body)
    scene.add_coupling(c0)
    scene.add_coupling(c1)
    units, where = scene.solve_units()
    assert len(units) == 3 and units[where[0][0]] is bone
    assert all(isinstance(units[where[i][0]], CouplingIsland) for i in (1, 2)) and where[1][0] != where[2][0]
    assert units[where[1][0]].guests == [bone]
    alone_bone = FixedBody(name="scapula")
    alone, link = muscle(0.0)
    link = Coupling(link.a, RigidPoints.from_world(alone_bone, alone.q[np.isclose(alone.q[:, 2], 0.0)]), 3e3)
    single = Scene()
    single.add_body(alone_bone)
    single.add_body(alone)
    single.add_coupling(link)
    for _ in range(20):
        scene.step(0.005)
        single.step(0.005)
    assert bone.step_count == 20
    np.testing.assert_allclose(m0.q, alone.q, atol=1e-12)
    assert m0.q[:, 2].min() < -0.0501  # it sags under gravity


def test_islands_in_parallel_threads_step_exactly_as_in_series():
    """The islands' solves are independent: threads change nothing, bit for bit."""
    results = []
    for parallel in (False, True):
        rng = np.random.default_rng(5)
        scene = Scene(parallel_islands=parallel)
        pairs = [_bone_and_muscle(0.3 * n, rng) for n in range(3)]
        for bone, muscle, link in pairs:
            scene.add_body(bone)
            scene.add_body(muscle)
            scene.add_coupling(link)
        for _ in range(10):
            scene.step(0.005)
        results.append(np.concatenate([m.q.ravel() for _, m, _ in pairs] + [b.position for b, _, _ in pairs]))
    np.testing.assert_array_equal(results[0], results[1])
