"""The node solve's loop decided on the device (NodeSolve(device_loop=True):
softvr.contact._node_loop_kernels, one batch a solve, on CUDA one graph with conditional nodes)
against the host's loop (device_loop=False), the reference it transcribes: MuJoCo's way with a
fast path, checked against the obviously-correct one.

Both take their decisions on the same float64 numbers with the same formulas in the same order
(the largest changes, the geometric tail, the observed rate, the plateau, the stall, the switch
to plain sweeps and back, the Gauss-Seidel wake, the narrower weights' retries), so there is no
tolerance to derive: every step must make the same sweeps and leave the same velocities, bit for
bit. The scenes are chosen so that every branch is taken at least once (asserted, so that a scene
that stops taking one fails here rather than leaving it unchecked): the bench cube over 120 steps
(plain windows, the narrower weights' retry counts), the shoulder (the Gauss-Seidel sweeps' wakes),
the candy pile (a plateau stop at its landing). What each solve reaches is checked against
physics elsewhere (the MLCP of eq. 5.5: tests/sim/test_node_arrays.py and the scene tests).
"""

import functools

import numpy as np
import pytest

from softvr.bench.contact import FULL_SCENE, softvr_scene
from softvr.contact.node_jacobi import NodeSolve
from softvr.scene import bundled, load_scene
from softvr.sim import _node_step


def _run(name: str, steps: int, device_loop: bool, monkeypatch) -> tuple[list, list]:
    """Per step the solve's outcome (sweeps, plain sweeps, plateau, wakes, the next start) and
    every body's velocities."""
    outcomes: list = []
    solve = NodeSolve.solve

    def recorded(self, tolerance, check_every=2, then=None, batch=None):
        result = solve(self, tolerance, check_every, then, batch)
        assert (self._loop is not None) == device_loop
        outcomes.append((result[0], self.plain_sweeps, self.plateaued, self.wakes, self.start_narrow))
        return result

    with monkeypatch.context() as patch:
        patch.setattr(_node_step, "NodeSolve", functools.partial(NodeSolve, device_loop=device_loop))
        patch.setattr(NodeSolve, "solve", recorded)
        velocities = []
        if name == "cube":
            scene, _ = softvr_scene(FULL_SCENE, "cpu", 1)
            for _ in range(steps):
                scene.step(FULL_SCENE.dt)
                velocities.append(np.concatenate([np.ravel(b.v) for b in scene.bodies]))
        else:
            variants = ("quick",) if name == "candy" else ()
            with load_scene(bundled(f"{name}.toml"), variants, frames=steps, width=64, height=48, haptics=False,
                            steps_per_frame=1) as example:
                for _ in range(steps):
                    example.step()
                    velocities.append(np.concatenate([np.ravel(b.v) for b in example.scene.bodies]))
    return outcomes, velocities


@pytest.mark.parametrize("name, steps, branch", [("cube", 120, "retry"), ("shoulder", 30, "wake"),
                                                 ("candy", 20, "plateau")])
def test_the_devices_loop_makes_the_host_loops_sweeps_bit_for_bit(name, steps, branch, monkeypatch):
    host, host_v = _run(name, steps, False, monkeypatch)
    device, device_v = _run(name, steps, True, monkeypatch)
    assert len(host) == steps
    taken = {"plain": any(o[1] for o in host), "plateau": any(o[2] for o in host),
             "wake": any(o[3] for o in host), "retry": len({o[4] for o in host}) > 1}
    assert taken[branch] and (branch == "wake" or taken["plain"]), taken
    assert device == host
    for step, (expected, got) in enumerate(zip(host_v, device_v)):
        assert got.tobytes() == expected.tobytes(), f"step {step}: velocities differ by {np.abs(got - expected).max()}"
