"""The node step (thesis eq. 5.6's sweeps on whole-scene arrays, one kernel source) on a device
other than the CPU's own memory: CUDA where present, and everywhere the CPU through host copies
(``Scene._host_copies``), which is a CUDA step's host traffic: the bodies' ``q``, ``v`` and
``fixed_velocity`` and the rigid bodies' poses uploaded before a step and downloaded after it,
external forces uploaded when written, the contacts and flags a step reads copied back; and the
CPU through host copies with the kernels' GPU forms (``Scene._gpu_forms``: a thread per contact,
candidate pair or node, what CUDA takes), whose soft cube (no node shared by two contacts: the
same operations) steps as the CPU's to the bit, and the shoulder (its contact step Jacobi on split
masses) within the scene's stop tolerance.

Each target is held to physics (statics, the discrete free fall with values a user writes
between steps, in place or by assignment) and to the CPU's own step on the same scene (the
issue's "a step on CUDA equals the CPU step" on the soft cube and the shoulder). Through host
copies the same compiled kernels run on the same numbers, so the CPU's step is matched to the
bit; CUDA's code may fuse a multiply-add that the CPU's rounds twice (~1e-16 relative an
operation), which a few steps of sweeps keep far below the 1 um allowed here unless a contact's
active set flips between the two (not run on a GPU yet: where CUDA misses by more, look there
first).

Tolerances on the physics come from the sweeps' stopping rule (SWEEP_TOLERANCE = 1e-5 m/s,
estimated from a geometric tail: 3x allowed), as in test_node_arrays.py.
"""

import numpy as np
import pytest
import warp as wp

from softvr import Scene, SimulationError
from softvr.collision import Plane
from softvr.contact.node_jacobi import NodeSolve
from softvr.device import LaunchBatch
from softvr.dynamics import EmbeddedPoints, FemBody, Material, RigidBody, RigidPoints
from softvr.scene import bundled, load_scene
from softvr.sim._node_step import SWEEP_TOLERANCE, NodeStepper
from softvr.volume import Volume, grid_tet_mesh

from tests.contact.test_node_aggregates import _beam
from tests.sim.test_node_rigid import _check_mlcp, _system

G = 9.81
VELOCITY_TOL = 3 * SWEEP_TOLERANCE  # [m/s]
#: Where a target runs: (Scene.device, Scene._host_copies, Scene._gpu_forms). The GPU forms of the
#: kernels (a thread per contact, candidate pair or node) are CUDA's own; on the CPU they run through
#: the host copies as a third target.
TARGETS = [pytest.param(("cpu", True, False), id="cpu-host-copies"),
           pytest.param(("cpu", True, True), id="cpu-gpu-forms")] + (
    [pytest.param(("cuda:0", False, False), id="cuda")] if wp.is_cuda_available() else [])
#: How far [m] a CUDA step may land from the CPU's (module docstring); the host copies: none.
CUDA_TOL = 1e-6


def _cube(cells=4, size=0.4, lift=0.002):
    spacing = np.full(3, size / cells)
    corner = np.array([-size / 2, -size / 2, lift])
    nodes, tets = grid_tet_mesh(Volume(np.zeros((cells,) * 3, np.uint8), spacing=spacing,
                                       origin=spacing / 2 + corner), cells)
    return FemBody(nodes, tets, Material(2.5e5, 0.25, 1000.0, alpha=0.0, beta=1e-3), name="cube")


def _box(scene, bottom):
    """A 10 cm rigid box (500 kg/m^3, its corners its collision points) added to ``scene`` over
    the origin, its bottom face at height ``bottom`` [m]."""
    half = np.array([0.05, 0.05, 0.05])
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half
    box = RigidBody.box(2 * half, 500.0, position=[0.0, 0.0, bottom + half[2]], name="box")
    scene.add_body(box, collision_points=RigidPoints(box, corners))
    return box


def _scene(body, target, plane=True):
    device, copies, gpu_forms = target
    scene = Scene(gravity=(0.0, 0.0, -G), device=device)
    scene._host_copies, scene._gpu_forms = copies, gpu_forms
    scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(body.q))[:, None],
                                                         np.ones((len(body.q), 1))))
    if plane:
        scene.add_plane(Plane(friction=0.5))
    return scene


def _assert_stepped_on(scene, target):
    assert scene.path == f"node arrays on {target[0]}" + (" (host copies)" if target[0] == "cpu" else "")
    assert scene._stepper.model.device == target[0] and scene._stepper.copies
    # The Jacobi sweeps' form: a thread per contact on a GPU or where asked (the target, or
    # pytest --gpu-forms for every scene).
    assert scene._stepper._recorded[5].parallel == (scene._gpu_forms or target[0] != "cpu")


@pytest.mark.parametrize("target", TARGETS)
def test_a_resting_cube_carries_its_weight(target):
    body = _cube()
    scene = _scene(body, target)
    for _ in range(120):
        solution = scene.step(1.0 / 60.0)
    _assert_stepped_on(scene, target)
    assert body.q[:, 2].min() > -1e-3
    # Static equilibrium: sum lambda_n = m g dt per step.
    carried = sum(i[:, 0].sum() for i in solution.impulses)
    assert carried == pytest.approx(body.mass.sum() * G / 60.0, rel=0.01)


@pytest.mark.parametrize("target", TARGETS)
def test_free_fall_takes_velocities_positions_and_forces_written_between_steps(target):
    # An undeformed body in free flight: K annihilates a translation and f_el = 0 at rest, so A v
    # = M v0 + dt (M g + f) has v = v0 + dt (g + f / m) at every node (f: a node's external force).
    body = _cube(lift=2.0)
    scene = _scene(body, target, plane=False)
    dt, n = 0.01, 10
    for _ in range(n):
        scene.step(dt)
    _assert_stepped_on(scene, target)
    np.testing.assert_allclose(body.v[:, 2], -G * n * dt, atol=VELOCITY_TOL)
    body.v[:, 0] += 0.5  # in place: the view the step downloaded into
    body.q = body.q + [0.0, 3.0, 0.0]  # assigned: a new array
    push = np.zeros_like(body.q)
    push[:, 2] = 2.0 * G * body.mass  # twice the weight, up: a net +g
    scene.external[0] = push
    x0, y0, z0, vz0 = body.q[:, 0].copy(), body.q[:, 1].copy(), body.q[:, 2].copy(), body.v[:, 2].copy()
    for _ in range(n):
        scene.step(dt)
    np.testing.assert_allclose(body.v[:, 0], 0.5, atol=VELOCITY_TOL)
    np.testing.assert_allclose(body.v[:, 2], vz0 + G * n * dt, atol=VELOCITY_TOL)
    np.testing.assert_allclose(body.q[:, 0], x0 + 0.5 * n * dt, atol=n * dt * VELOCITY_TOL)
    np.testing.assert_allclose(body.q[:, 1], y0, atol=n * dt * VELOCITY_TOL)
    # Velocity first, then position: z = z0 + n dt vz0 + g dt^2 n (n + 1) / 2.
    np.testing.assert_allclose(body.q[:, 2], z0 + n * dt * vz0 + G * dt * dt * n * (n + 1) / 2,
                               atol=n * dt * VELOCITY_TOL)


@pytest.mark.parametrize("target", [pytest.param(("cpu", False, False), id="cpu")] + TARGETS)
def test_a_rigid_body_that_diverges_in_its_unconstrained_step_is_named_and_nothing_moves(target):
    # A NaN angular velocity written into a rigid box beside an FEM cube: the step stops with the
    # box's own report (its velocity, as RigidBody.step reports it: tests/dynamics/test_rigid.py),
    # not a node's, and neither body moves. On the CPU's own arrays the box's flags are read
    # before the sweeps; off them (the host copies, CUDA) after the whole step, through which the
    # NaN has reached the sweeps and the nodes' flags: the unconstrained step's flags first
    # (RigidNodes.check_before).
    body = _cube(lift=0.5)
    scene = _scene(body, target)
    box = _box(scene, bottom=0.6)
    scene.step(0.01)
    box.v[4] = np.nan
    q, position = body.q.copy(), box.position.copy()
    with pytest.raises(SimulationError, match=r"box: diverged at step 2 \(velocity NaN/inf\)"):
        scene.step(0.01)
    np.testing.assert_array_equal(body.q, q)
    np.testing.assert_array_equal(box.position, position)


@pytest.mark.parametrize("target", TARGETS)
def test_a_rigid_box_beside_an_fem_body_falls_from_where_it_is_put_between_steps(target):
    # The rigid box's two nodes (linear, angular velocity) in the same arrays: free fall v = v0 - g
    # t, and a pose written in place between steps (its mirror pushed) is where it falls from.
    body = _cube()
    scene = _scene(body, target)
    half = np.array([0.05, 0.05, 0.05])
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half
    box = RigidBody.box(2 * half, 500.0, position=[2.0, 0.0, 3.0])
    scene.add_body(box, collision_points=RigidPoints(box, corners))
    dt, n = 0.01, 10
    for _ in range(n):
        scene.step(dt)
    _assert_stepped_on(scene, target)
    np.testing.assert_allclose(box.v, [0, 0, -G * n * dt, 0, 0, 0], atol=VELOCITY_TOL)
    box.position[2] = 5.0  # in place
    box.v = np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0])  # assigned
    for _ in range(n):
        scene.step(dt)
    np.testing.assert_allclose(box.v, [0, 1.0, -G * n * dt, 0, 0, 0], atol=VELOCITY_TOL)
    np.testing.assert_allclose(box.position, [2.0, n * dt, 5.0 - G * dt * dt * n * (n + 1) / 2],
                               atol=n * dt * VELOCITY_TOL)


@pytest.mark.parametrize("target", TARGETS)
def test_a_beam_too_stiff_for_the_sweeps_steps_on_the_cpus_arrays_and_meets_eq_5_5(target):
    # The sweeps decline this clamped beam (over their work limits); the factored solve that
    # takes it is CPU-only, so off the CPU's own arrays the scene falls back to them (not to the
    # per-object path) and each step still solves the MLCP of eq. 5.5 (the free rows' momentum
    # balance and complementarity, _check_mlcp).
    body = _beam()
    body.q[:] = body.q - [0.0, 0.0, 1.0 - 0.0005]  # its underside 0.5 mm above the plane z = 0
    body.v[:] = 0.0
    body.v[:, 2] = -0.3 * body.q[:, 0] / body.q[:, 0].max()  # swinging down about the clamp
    body.v[body.fixed] = 0.0
    scene = _scene(body, target)
    dt, pushing = 0.01, 0
    for _ in range(6):
        systems = [_system(b, dt, scene.gravity) for b in scene.bodies]
        solution = scene.step(dt)
        _check_mlcp(scene, systems, solution, dt, 0.5)
        pushing += sum(int((lam[:, 0] > 0).sum()) for lam in solution.impulses)
    stepper = scene._stepper
    assert (stepper.model.device, stepper.copies) == ("cpu", False)
    assert type(stepper._recorded[5]).__name__ == "FactoredSolve"
    assert pushing >= 10


def _shoulder(target):
    # The haptic handle follows its script on the simulation's clock (haptics on, a loop thread
    # reads it on the wall clock, and two runs differ).
    example = load_scene(bundled("shoulder.toml"), frames=4, width=64, height=48, haptics=False)
    example.scene.device, example.scene._host_copies, example.scene._gpu_forms = target
    return example


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("name", ["soft cube", "shoulder"])
def test_a_step_on_the_target_equals_the_cpu_step(target, name):
    runs = []
    for where in (("cpu", False, False), target):
        if name == "soft cube":
            body = _cube(cells=6, size=0.6, lift=0.05)
            scene = _scene(body, where)
            for _ in range(30):
                scene.step(1.0 / 60.0)
            runs.append([body.q.copy(), body.v.copy()])
        else:
            with _shoulder(where) as example:
                for _ in range(4):
                    example.step()
                assert type(example.scene._stepper).__name__ == "NodeStepper"
                runs.append([np.concatenate([np.ravel(b.q if hasattr(b, "q") else b.position),
                                             np.ravel(b.v)]) for b in example.scene.bodies])
    tol = 0.0 if target[0] == "cpu" else CUDA_TOL
    if name == "shoulder" and (target[2] or target[0] != "cpu"):
        # Its Gauss-Seidel sweeps' contact step in the GPU forms is Jacobi over the contacts (split
        # masses): another path to the same fixed point, each step's velocities within 3x the
        # scene's stop tolerance of it (pgs_tolerance 3e-4 m/s; SWEEP_TOLERANCE's allowance), so two
        # runs within 2 x 3 x 3e-4 m/s, and the positions within 4 steps x 20 ms of that.
        tol = 2 * 3 * 3e-4
    for expected, got in zip(*runs):
        np.testing.assert_allclose(got, expected, rtol=0, atol=tol)


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("name", ["cube and box", "shoulder", "candy-adhesive"])
def test_a_step_as_one_batch_equals_its_separate_batches(target, name, monkeypatch):
    # NodeStepper._whole_step lays a step after a step size's first out as one LaunchBatch (on
    # CUDA one graph) made of the separate batches' launches, in their order; the reference is
    # those batches run one after another (_whole_step patched away). Nothing between them is
    # read or decided on the host, so the same kernels on the same numbers: equal to the bit, over
    # steps that carry warm starts, adhesion's bonds (the candy, evolve chosen by the loop's buffer
    # flags) and a rigid box's unconstrained step and divergence flags (inside the batch).
    whole = NodeStepper._whole_step
    runs = []
    for one_batch in (False, True):
        used = [0]

        def counted(self):
            batch = whole(self)
            used[0] += batch is not None
            return batch if one_batch else None

        monkeypatch.setattr(NodeStepper, "_whole_step", counted)
        if name == "cube and box":
            body = _cube(lift=0.01)
            scene = _scene(body, target)
            _box(scene, bottom=0.41)  # on the cube's top face
            for _ in range(40):
                scene.step(1.0 / 60.0)
            bodies = scene.bodies
        else:
            variants = ("quick",) if name.startswith("candy") else ()
            with load_scene(bundled(f"{name}.toml"), variants, frames=12, width=64, height=48, haptics=False,
                            steps_per_frame=1) as example:
                example.scene.device, example.scene._host_copies, example.scene._gpu_forms = target
                for _ in range(12):
                    example.step()
                scene, bodies = example.scene, example.scene.bodies
        runs.append([np.concatenate([np.ravel(b.q if hasattr(b, "q") else b.position), np.ravel(b.v)])
                     for b in bodies])
        steps = 40 if name == "cube and box" else 12
        assert used[0] == steps - 1, "every step but the first can be one batch"
    for separate, together in zip(*runs):
        np.testing.assert_array_equal(together, separate)


def test_a_device_that_is_not_there_is_named_before_anything_steps():
    # Scene.device is read when the scene's arrays are built (its first step): an unknown name, or
    # CUDA where none is present, stops with the field, what was expected and what was found,
    # and the bodies stay where they were.
    from softvr.errors import InputError

    cases = ["gpu"] + ([] if wp.is_cuda_available() else ["cuda"])
    for device in cases:
        body = _cube(lift=1.0)
        scene = _scene(body, (device, False, False), plane=False)
        start = body.q.copy()
        with pytest.raises(InputError) as err:
            scene.step(0.01)
        assert "device" in str(err.value) and repr(device) in str(err.value)
        np.testing.assert_array_equal(body.q, start)


@pytest.mark.parametrize("gpu_forms", [False, True], ids=["cpu forms", "gpu forms"])
@pytest.mark.parametrize("name", ["soft cube", "shoulder", "candy", "candy-adhesive"])
def test_the_sweeps_batched_for_cuda_graphs_read_nothing_back_inside_a_batch(name, gpu_forms, monkeypatch):
    # Off the CPU's own arrays a step size's first step is four LaunchBatches (on CUDA four
    # captured graphs): the launches before the sweeps (dynamics, collision: NodeStepper._stages),
    # the solve's whole loop (NodeSolve._record_loop: its sweeps and their checks, the stop
    # decided on the device), and what follows it (NodeStepper._after_sweeps: adhesion's evolve,
    # the settling, the rigid bodies' integration, for the sweep buffer the loop marked); the
    # solver is chosen between them, from the detection's contacts. Every later step is all of
    # that as one batch (NodeStepper._whole_step: one graph a step), the conditions of
    # wp.capture_while / capture_if read through their pointers here, graph nodes on CUDA. A graph
    # records launches only: a host read inside a batch (an array's numpy(), a copy, a
    # synchronize) would run once, at the capture, and never again. Through the host copies the
    # batches run on the CPU, with every such read refused inside them; every solve is launched
    # on the device (its sweeps run only inside its batch).
    inside, batches, solves = [False], [0], [0]
    original = LaunchBatch.__call__
    solve = NodeSolve.launch

    def batch(self):
        inside[0] = True
        batches[0] += 1
        try:
            original(self)
        finally:
            inside[0] = False

    def on_device(self, tolerance, batch=None):
        solves[0] += 1
        return solve(self, tolerance, batch)

    def refused(call):
        def guard(*args, **kwargs):
            assert not inside[0], f"{call.__name__} inside a launch batch"
            return call(*args, **kwargs)
        return guard

    monkeypatch.setattr(LaunchBatch, "__call__", batch)
    monkeypatch.setattr(NodeSolve, "launch", on_device)
    monkeypatch.setattr(wp.array, "numpy", refused(wp.array.numpy))
    for call in ("copy", "synchronize", "synchronize_device", "synchronize_stream"):
        monkeypatch.setattr(wp, call, refused(getattr(wp, call)))
    sweeps = 0
    if name == "soft cube":
        body = _cube(cells=6, size=0.6, lift=0.02)
        scene = _scene(body, ("cpu", True, gpu_forms))
        for _ in range(20):
            sweeps += scene.step(1.0 / 60.0).iterations
    else:
        variants = ("quick",) if name.startswith("candy") else ()
        with load_scene(bundled(f"{name}.toml"), variants, frames=20, width=64, height=48, haptics=False,
                        steps_per_frame=1) as example:
            example.scene._host_copies, example.scene._gpu_forms = True, gpu_forms
            for _ in range(20):
                example.step()
                sweeps += example.scene.last_solution.iterations
            scene = example.scene
    assert scene.path == "node arrays on cpu (host copies)"
    # Every step's solve launched on the device: four batches on the first step, one on each later.
    assert sweeps > 0 and solves[0] == 20 and batches[0] == 4 + 19
