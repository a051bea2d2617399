"""The plateau stop of the node sweeps (softvr.contact.node_jacobi.NodeSolve._plateau): sweeps
whose largest change hovers under the tolerance without falling stop there, and what they stop
on is held to the MLCP of eq. 5.5.

The geometric-tail stop (node_jacobi.tail_error <= tolerance) is put out of reach (the tail
taken as infinite), so only the plateau rule can end a step before the scene's cap. That is the
host's loop (NodeSolve(device_loop=False)), whose tail_error can be replaced; the device's loop
takes the same decisions bit for bit, its plateau stop on the candy pile included
(tests/contact/test_node_loop.py). Tolerances: the checker of tests/sim/test_node_arrays.py (3x
the sweeps' tolerance).
"""

import functools

from softvr.contact import node_jacobi
from softvr.contact.node_jacobi import NodeSolve
from softvr.sim import _node_step

from tests.sim.test_node_arrays import _cube, _scene, check_mlcp_steps

DT = 1.0 / 60.0


def test_sweeps_that_hover_under_the_tolerance_stop_and_solve_the_mlcp_of_eq_5_5(monkeypatch):
    solves = []
    solve = NodeSolve.solve

    def record(self, tolerance, check_every=2, then=None, batch=None):
        result = solve(self, tolerance, check_every, then, batch)
        solves.append((result[0], self.plateaued, self.max_sweeps))
        return result

    monkeypatch.setattr(_node_step, "NodeSolve", functools.partial(NodeSolve, device_loop=False))
    monkeypatch.setattr(node_jacobi, "tail_error", lambda *args: float("inf"))
    monkeypatch.setattr(node_jacobi.NodeSolve, "solve", record)
    body = _cube()
    body.v[:] = [0.3, 0.0, -0.5]  # lands sliding: friction, and then sticking, in the steps checked
    scene = _scene(body)
    assert check_mlcp_steps(body, scene, DT, 20, friction=0.5) >= 10
    # No step at the cap (where the tail stop alone ends them): all on the plateau.
    assert all(plateaued and sweeps < cap for sweeps, plateaued, cap in solves), solves
