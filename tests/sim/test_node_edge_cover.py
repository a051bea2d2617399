"""One contact per touching feature pair on the node arrays (issue 16): an edge pair on a patch the
vertex-triangle contacts already hold makes no contact of its own (`edge_pair_covered` in
softvr.collision._node_kernels), while edges that cross where no vertex touches keep theirs.

Truths: statics (a block resting on another is carried by the contacts between them with
m g, the normal rows of eq. 5.5 at rest) and geometry (two cubes turned 45 degrees about
perpendicular axes can come no closer than 2 h sqrt(2) centre to centre, edge on edge, as in
tests/contact/test_edge_contact.py for rigid cubes).
"""

import numpy as np

from softvr import Scene
from softvr.dynamics import FemBody, Material
from softvr.dynamics.rigid import quat_to_matrix, quat_from_rotvec
from softvr.sim._node_step import SWEEP_TOLERANCE
from softvr.volume import Volume, grid_tet_mesh
from tests.sim.test_node_surfaces import _add_with_surface, _stack

G = 9.81
VERTEX_TRIANGLE, EDGE_EDGE = 3, 4  # contact id tags (id >> 60)


def _upper_impulse_z(solution, upper: int) -> float:
    """Vertical impulse [N s] the contacts between bodies put on body ``upper`` in one step."""
    total = 0.0
    for contacts, lam, frames in zip(solution.contacts, solution.impulses, solution.frames):
        if contacts.b is None:
            continue
        world_z = np.einsum("ci,ci->c", lam, frames[:, :, 2])
        total += world_z.sum() * ((contacts.a.body == upper) - (contacts.b.body == upper))
    return total


def test_a_block_resting_on_a_block_has_one_contact_per_touching_pair_carrying_m_g():
    """Two soft blocks face to face, edge contacts on: the contacts between them are the
    vertex-triangle pairs alone (each vertex against the other block once; the crossing edges of
    the two faces add none), and at rest they carry the upper block's weight, m g dt a step
    (eq. 5.5 with the upper block's momentum unchanged). Tolerance: the sweeps stop within
    SWEEP_TOLERANCE [m/s] of the solution, so the impulse is m g dt within m times a few
    tolerances, plus what the settling block still accelerates (< 1e-4 m/s a step after 90
    steps): 1 % of m g dt is ~10x both."""
    scene, (lower, upper) = _stack(True)
    dt = 1.0 / 60.0
    for _ in range(90):
        v_before = upper.v.reshape(-1, 3).mean(axis=0)
        solution = scene.step(dt)
    kinds, ids = [], []
    for contacts in solution.contacts:
        if contacts.b is not None:
            kinds += [int(i) >> 60 for i in contacts.ids]
            ids += [int(i) for i in contacts.ids]
    assert set(kinds) == {VERTEX_TRIANGLE}
    assert len(ids) == len(set(ids))  # one contact per (vertex, other body) pair
    m = float(upper.mass.sum())
    dv = upper.v.reshape(-1, 3).mean(axis=0)[2] - v_before[2]
    assert abs(dv) < 1e-4  # at rest
    np.testing.assert_allclose(_upper_impulse_z(solution, 1), m * (G * dt + dv), rtol=1e-2)
    assert 3 * SWEEP_TOLERANCE * m < 1e-3 * m * G * dt  # the tolerance's share (see docstring)


def _turned_cube(half, axis, centre, velocity, material):
    nodes, tets = grid_tet_mesh(Volume(np.zeros((1, 1, 1), np.uint8), spacing=(2 * half,) * 3,
                                       origin=(0.0, 0.0, 0.0)), 1)
    turn = quat_to_matrix(quat_from_rotvec(np.pi / 4 * np.asarray(axis, float)))
    body = FemBody((nodes - nodes.mean(axis=0)) @ turn.T + centre, tets, material)
    body.v = np.tile(np.asarray(velocity, float), (len(nodes), 1))
    return body


def test_crossing_edges_of_soft_cubes_keep_their_edge_contacts():
    """Soft (stiff) cubes a and b turned 45 degrees about x and y: a moves down onto b and
    their edges cross at right angles, where no vertex touches a face. The edge pair is not
    covered (no end of either edge touches the other cube), so it keeps its contact and the
    centres stay >= 2 h sqrt(2) apart; vertex-triangle contacts alone let them sink ~2 cm
    (test_edge_contact.py). Tolerance: the cubes' own compression under the 0.5 m/s impact
    (E = 1e8 Pa: a few um) and the contact's linearization over a step: 0.5 mm."""
    half = 0.05
    stiff = Material(1e8, 0.3, 500.0, alpha=0.0, beta=1e-3)
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.0, edge_contacts=True)
    a = _turned_cube(half, (1, 0, 0), (0.0, 0.0, 2 * half * np.sqrt(2) + 0.004), (0.0, 0.0, -0.5), stiff)
    b = _turned_cube(half, (0, 1, 0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), stiff)
    for body in (a, b):
        _add_with_surface(scene, body)
    closest, kinds = np.inf, set()
    for _ in range(40):
        solution = scene.step(0.005)
        assert type(scene._stepper).__name__ == "NodeStepper"
        kinds |= {int(c.ids[0]) >> 60 for c in solution.contacts if c.b is not None}
        closest = min(closest, a.q.mean(axis=0)[2] - b.q.mean(axis=0)[2])
    assert EDGE_EDGE in kinds
    assert closest > 2 * half * np.sqrt(2) - 5e-4
