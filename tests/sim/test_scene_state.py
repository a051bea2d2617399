"""Scene.save_state / restore_state: going back to a saved state and stepping again retraces the
same trajectory (the step is a deterministic function of the state: after a restore the path's
launches are rebuilt from the restored bodies and warm starts), on the rigid arrays, the node
arrays and the per-object path alike; and a restore into another scene is refused.

Tolerances: the rigid arrays replay bit for bit (same launches, same inputs, their PGS starts
from the restored warm starts). The FEM paths retrace to their solvers' tolerance: the node
sweeps restart from the explicit guess and re-estimate their Chebyshev bounds at the restored
state, the per-object path's CG is preconditioned by a lagged LU a restore does not bring back,
so each step lands within the velocity tolerance (3 x 1e-5 m/s, as in test_node_arrays.py) of
the same solution: after n steps of dt the positions within n * 3e-5 m/s * dt.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import EmbeddedPoints, FemBody, KinematicBody, Material, RigidBody, RigidPoints
from softvr.errors import InputError
from softvr.sim import SceneState
from softvr.sim._node_step import SWEEP_TOLERANCE
from softvr.volume import Volume, grid_tet_mesh


def _cube_body(lift):
    spacing = np.full(3, 0.1)
    nodes, tets = grid_tet_mesh(Volume(np.zeros((3, 3, 3), np.uint8), spacing=spacing,
                                       origin=spacing / 2 + [-0.15, -0.15, lift]), 3)
    return FemBody(nodes, tets, Material(2e5, 0.3, 1000.0, alpha=0.0, beta=1e-3), name="cube")


def _fem_scene(node_arrays):
    scene = Scene(node_arrays=node_arrays)
    body = _cube_body(0.01)
    body.v = np.tile([0.6, 0.0, 0.0], (len(body.q), 1))  # sliding: friction acts every step
    scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(body.q))[:, None],
                                                         np.ones((len(body.q), 1))))
    scene.add_plane(Plane(friction=0.5))
    return scene, lambda: body.q.copy()


def _rigid_scene():
    scene = Scene()
    box = RigidBody(2.0, [0.02, 0.02, 0.02], position=(0.0, 0.0, 0.11), velocity=(0.3, 0.0, 0.0))
    scene.add_body(box, collision_box=(0.1, 0.1, 0.1))
    scene.add_plane(Plane(friction=0.4))
    return scene, lambda: np.concatenate([box.position, box.orientation])


def _probe_scene():
    # A kinematic sphere pressing into a clamped FEM block: the node arrays with a driven body.
    scene, positions = _fem_scene(True)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * 0.05

    def pose(t):
        return (0.0, 0.0, 0.37 - 0.05 * t), (1.0, 0.0, 0.0, 0.0)

    probe = KinematicBody(pose, name="probe")
    scene.add_body(probe, collision_points=RigidPoints(probe, corners))
    return scene, lambda: np.concatenate([positions().ravel(), probe.position])


DT, STEPS = 1.0 / 60.0, 8
FEM_TOLERANCE = STEPS * 3 * SWEEP_TOLERANCE * DT  # [m]


@pytest.mark.parametrize("build, path, tolerance", [
    (_rigid_scene, "RigidStepper", 0.0),
    (lambda: _fem_scene(True), "NodeStepper", FEM_TOLERANCE),
    (_probe_scene, "NodeStepper", FEM_TOLERANCE),
    (lambda: _fem_scene(False), None, FEM_TOLERANCE),
], ids=["rigid arrays", "node arrays", "node arrays with a kinematic body", "per object"])
def test_a_restored_scene_retraces_its_steps(build, path, tolerance):
    scene, positions = build()
    dt = DT
    for _ in range(10):  # into contact: warm starts to carry
        scene.step(dt)
    saved, at_save = scene.save_state(), positions()
    first = []
    for _ in range(STEPS):
        scene.step(dt)
        first.append(positions())
    assert type(scene._stepper).__name__ == path if path else scene._stepper is None
    scene.restore_state(saved)
    assert scene.time == saved.time
    np.testing.assert_array_equal(positions(), at_save)
    again = []
    for _ in range(STEPS):
        scene.step(dt)
        again.append(positions())
    np.testing.assert_allclose(np.array(again), np.array(first), rtol=0, atol=tolerance)
    assert np.abs(np.array(first) - at_save).max() > 100 * tolerance  # the steps did move it
    # The saved state is a copy: stepping after a restore did not change it.
    scene.restore_state(saved)
    np.testing.assert_array_equal(positions(), at_save)


def test_a_state_restores_only_into_its_own_layout():
    scene, _ = _rigid_scene()
    saved = scene.save_state()
    scene.add_plane(Plane(point=(0.0, 0.0, -1.0)))
    with pytest.raises(InputError, match="a state saved from this scene's layout"):
        scene.restore_state(saved)
    with pytest.raises(InputError, match="a SceneState"):
        scene.restore_state({"time": 0.0})
    assert isinstance(saved, SceneState)
