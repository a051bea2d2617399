"""The node sweeps' contact PGS visits only the contacts that push, hold or would
(softvr.contact._node_jacobi_kernels.screen): the speculative contacts that stay apart are
skipped. Skipping changes the path of the iteration, not its fixed point, so every contact step
must still solve the MLCP of thesis eq. 5.5 (A v = b + J^T lambda, 0 <= lambda_n _|_
n . v + gap / dt >= 0, friction in the disc), checked against A and b assembled by the
per-object code (tests/sim/test_node_arrays.py's checker), to 3x the sweeps' tolerance.

The scene makes the skip matter: a block turned about two axes lands on a corner with a contact
margin wider than the block, so every node has a speculative plane contact from the first step;
the corner's impulse tips the block, which brings the contacts beside it, skipped until then,
below their targets in the middle of a sweep.
"""

import numpy as np
import pytest

from softvr.contact import node_jacobi
from softvr.dynamics import FemBody, Material
from softvr.sim import _node_step

from tests.sim.test_node_arrays import _cube, _scene, check_mlcp_steps

DT = 1.0 / 60.0


def _tilted(cube: FemBody, lift: float) -> FemBody:
    """``cube`` turned 25 degrees about x and 15 about y, its lowest node ``lift`` [m] above z = 0."""
    a, b = np.radians(25.0), np.radians(15.0)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rest = (cube.rest - cube.rest.mean(0)) @ (ry @ rx).T
    rest[:, 2] += lift - rest[:, 2].min()
    return FemBody(rest, cube.tets, cube.material, name="tilted")


@pytest.mark.parametrize("stiff", [False, True], ids=["jacobi", "coarse"])
def test_a_tilted_block_landing_on_a_corner_solves_eq_5_5_with_the_far_contacts_skipped(monkeypatch, stiff):
    # stiff: a gummy-stiff 6 cm block at the candy's step size, which takes the coarse correction
    # (its contacts then also move the block's six rigid velocities).
    _land_and_check(monkeypatch, stiff)


def test_the_contact_kernels_striding_over_the_contacts_in_several_threads_solve_the_same(monkeypatch):
    # On CUDA the screen, the contact metric and the rigid marks stride over the contacts in
    # many threads (one on the CPU): three threads here, so that every contact is someone's.
    monkeypatch.setattr(node_jacobi, "_contact_threads", lambda device: 3)
    _land_and_check(monkeypatch, False)


def _land_and_check(monkeypatch, stiff):
    dt = 0.008 if stiff else DT
    material = Material(2e6, 0.35, 1000.0, alpha=0.0, beta=2e-3) if stiff else None
    cube = _cube(cells=3, size=0.06, material=material) if stiff else _cube(cells=3, size=0.3)
    body = _tilted(cube, lift=0.002)
    body.v[:] = [0.0, 0.0, -0.5]
    size = np.ptp(body.q, axis=0).max()
    solves = []
    original = _node_step.NodeStepper._solver

    def solver(self, step):
        solve = original(self, step)
        solves.append(solve)
        return solve

    monkeypatch.setattr(_node_step.NodeStepper, "_solver", solver)
    scene = _scene(body, contact_margin=2.0 * size)
    live, contacts = [], []
    step = scene.step

    def counted(h):
        out = step(h)
        count = int(scene._stepper.state.contacts.count.numpy()[0])
        contacts.append(count)
        live.append(int(solves[-1].live.numpy()[:count].sum()))
        return out

    monkeypatch.setattr(scene, "step", counted)
    assert check_mlcp_steps(body, scene, dt, 30, friction=0.5) >= 25
    assert (solves[-1].coarse.count > 0) == stiff
    # Every node had a contact on every step, and on each step the last sweep visited fewer
    # than half of them: the skip was taken.
    assert min(contacts) == len(body.q)
    assert max(n / c for n, c in zip(live, contacts)) < 0.5


def test_a_block_clamped_on_the_plane_sags_onto_it_and_solves_eq_5_5_past_its_fixed_nodes_contacts(monkeypatch):
    """The block's left face is clamped on the plane (its bottom nodes there touch it and can move
    nothing, as the candy's Jell-O bottom: the CPU's contact step lists only the movable contacts,
    node_jacobi's ``list_movers``), the rest of it sags under gravity onto the plane. Each contact
    step solves the MLCP of eq. 5.5 against A and b assembled by the per-object code (the checker
    of tests/sim/test_node_arrays.py, 3x the sweeps' tolerance), with contacts of both kinds."""
    solves = []
    original = _node_step.NodeStepper._solver
    monkeypatch.setattr(_node_step.NodeStepper, "_solver",
                        lambda self, step: solves.append(original(self, step)) or solves[-1])
    body = _cube(cells=4, size=0.4, lift=0.0005, fixed=lambda x: x[:, 0] < -0.19)
    scene = _scene(body)
    assert check_mlcp_steps(body, scene, DT, 20, friction=0.5) >= 15
    state = scene._stepper.state
    count = int(state.contacts.count.numpy()[0])
    movable = node_jacobi.movable_contacts(scene._stepper.model, state)
    pushing = int((np.abs(state.contacts.impulse.numpy()[:count, 0]) > 0).sum())
    assert 0 < movable < count and pushing > 0, (movable, count, pushing)
