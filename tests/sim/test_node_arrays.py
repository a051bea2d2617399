"""FEM bodies on planes stepped on whole-scene arrays (softvr.sim.NodeModel: eq. 5.6's sweeps,
node-block D_A, Chebyshev accelerated, no factorization), held to SciPy's direct solves of the
same step, to the MLCP of eq. 5.5, to a static solution and to closed forms.

Tolerances come from the sweeps' stopping rule: they stop when the estimated velocity error is
below SWEEP_TOLERANCE = 1e-5 m/s (the per-object PGS tolerance), estimated from the last change
and the iteration's asymptotic rate; the estimate is a geometric tail, so the tests allow 3x.
"""

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from softvr import Scene, SimulationError
from softvr.collision import Plane, Sphere
from softvr.contact import Adhesion
from softvr.contact.node_jacobi import chebyshev_weights
from softvr.dynamics import EmbeddedPoints, FemBody, Material
from softvr.sim import node_model_supported
from softvr.sim._node_step import SWEEP_TOLERANCE, spectrum
from softvr.volume import Volume, grid_tet_mesh

G = 9.81
VELOCITY_TOL = 3 * SWEEP_TOLERANCE  # [m/s]


def _cube(cells=4, size=0.4, lift=0.002, material=None, fixed=None):
    spacing = np.full(3, size / cells)
    corner = np.array([-size / 2, -size / 2, lift])
    nodes, tets = grid_tet_mesh(Volume(np.zeros((cells,) * 3, np.uint8), spacing=spacing,
                                       origin=spacing / 2 + corner), cells)
    material = material or Material(2.5e5, 0.25, 1000.0, alpha=0.0, beta=1e-3)
    fixed = None if fixed is None else fixed(nodes)
    return FemBody(nodes, tets, material, fixed=fixed, name="cube")


def _scene(body, plane=True, **kw):
    scene = Scene(gravity=(0.0, 0.0, -G), **kw)
    scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(body.q))[:, None],
                                                         np.ones((len(body.q), 1))))
    if plane:
        scene.add_plane(Plane(friction=0.5))
    return scene


def _solve_step(body, scene, dt):
    """This step's A, b (eq. 5.2) and SciPy's direct solution of A v = b over the free velocities."""
    system = body.step_system(dt, scene.gravity)
    a = system.matrix.tocsc()
    free = ~system.prescribed
    v = system.value.copy()
    rhs = system.rhs[free] - a[free][:, ~free] @ system.value[~free]
    v[free] = spla.spsolve(a[free][:, free], rhs)
    return system, v.reshape(-1, 3)


def test_a_step_without_contact_is_scipy_direct_solve_of_eq_5_2():
    # A deformed, spinning cube in free flight: the sweeps must land on A^-1 b (no contact rows).
    body = _cube(lift=0.5)
    rng = np.random.default_rng(3)
    body.q = body.q + 0.01 * rng.standard_normal(body.q.shape)
    body.v = np.cross([0.0, 0.0, 2.0], body.q) + 0.1 * rng.standard_normal(body.q.shape)
    scene = _scene(body)
    dt = 1.0 / 60.0
    for _ in range(3):
        _, expected = _solve_step(body, scene, dt)
        q0 = body.q.copy()
        scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper"
        np.testing.assert_allclose(body.v, expected, atol=VELOCITY_TOL, rtol=0)
        np.testing.assert_allclose(body.q, q0 + dt * body.v, atol=1e-12)


def test_free_fall_of_an_undeformed_body_is_the_discrete_closed_form():
    # K annihilates a translation and f_el = 0 at rest, so A v = M v0 + dt M g has v = v0 + dt g:
    # after n steps v = -g n dt, z = z0 - g dt^2 n (n + 1) / 2 (velocity first, then position).
    body = _cube(lift=2.0)
    scene = _scene(body, plane=False)
    z0, dt, n = body.q[:, 2].copy(), 0.01, 40
    for _ in range(n):
        scene.step(dt)
    np.testing.assert_allclose(body.v[:, 2], -G * n * dt, atol=VELOCITY_TOL)
    np.testing.assert_allclose(body.v[:, :2], 0.0, atol=VELOCITY_TOL)
    np.testing.assert_allclose(body.q[:, 2], z0 - G * dt * dt * n * (n + 1) / 2, atol=n * dt * VELOCITY_TOL)


def test_free_bodies_keep_the_exact_impulse_of_gravity_beside_a_held_body_whose_guess_carries_a_share():
    # Newton over a free body: its momentum changes by M g dt a step, whatever it does inside
    # (eq. 5.2 summed over a body's nodes: K takes nothing from a uniform motion). Two cubes
    # spinning in flight beside a clamped cube set swinging: the first guess
    # (node_arrays.record_start) carries a fitted share < 1 of the clamped cube's last change
    # and all of the free cubes', so their guessed momentum is exact, and the sweeps keep it
    # here (with the share on the free cubes too, the reverted form of session 13, the vertical
    # momentum ends ~2e-5 of M g t off). The sweeps conserve momentum only to their tolerance in
    # general: the same cubes deformed at the start end ~3e-7 off on either guess. Round-off:
    # ~1e-16 a node and step, ~1e-14 after 20 steps of 125 nodes; 1e-11 of M g t leaves room.
    free = [_cube(cells=4, size=0.2, lift=1.0 + 0.5 * k) for k in range(2)]
    clamped = _cube(cells=4, size=0.2, lift=0.0, fixed=lambda nodes: nodes[:, 2] < 1e-9)
    clamped.q = clamped.q + [1.0, 0.0, 0.0]
    clamped.v = np.cross([0.0, 0.0, 8.0], clamped.q - [1.0, 0.0, 0.0]) * (clamped.q[:, 2:] / 0.2)
    scene = Scene(gravity=(0.0, 0.0, -G))
    for k, body in enumerate(free):
        body.v = np.cross([3.0 * k - 1.0, 2.0, 5.0], body.q - body.q.mean(0)) + [0.3 * k, -0.2, 1.0]
        scene.add_body(body)
    scene.add_body(clamped)
    p0 = [np.sum(b.mass[:, None] * b.v, axis=0) for b in free]
    dt, steps = 1.0 / 60.0, 20
    for _ in range(steps):
        scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    for body, start in zip(free, p0):
        mass = np.sum(body.mass)
        impulse = np.sum(body.mass[:, None] * body.v, axis=0) - start
        np.testing.assert_allclose(impulse, [0.0, 0.0, -mass * G * steps * dt], rtol=0,
                                   atol=1e-11 * mass * G * steps * dt)


def test_a_contact_step_solves_the_mlcp_of_eq_5_5():
    """A v = b + J^T lambda with lambda_n >= 0, n . v >= -gap / dt and complementarity, where A, b
    are this step's and J^T lambda is read from the solution (one node per contact)."""
    body = _cube()
    scene = _scene(body)
    dt = 1.0 / 60.0
    assert check_mlcp_steps(body, scene, dt, 40, friction=0.5) >= 10


def check_mlcp_steps(body, scene, dt, steps, friction):
    """Step ``scene`` ``steps`` times, holding each step with contacts (points of ``body``, one
    node each, vs planes of friction coefficient ``friction``) to the MLCP of eq. 5.5; returns
    how many steps had contacts."""
    checked = 0
    for step in range(steps):
        system, _ = _solve_step(body, scene, dt)
        solution = scene.step(dt)
        if not solution.contacts:
            continue
        impulse = np.zeros((len(body.q), 3))
        for contacts, lam, frames in zip(solution.contacts, solution.impulses, solution.frames):
            world = np.einsum("ci,cij->cj", lam, frames)
            np.add.at(impulse, contacts.a.blocks[:, 0], world)
            vn = np.einsum("ci,ci->c", body.v[contacts.a.blocks[:, 0]], contacts.normal)
            assert (lam[:, 0] >= 0).all()
            assert (vn >= -contacts.gap / dt - VELOCITY_TOL).all()
            # Complementarity: a pushing contact has closed to its constraint.
            pushing = lam[:, 0] > 1e-6 * body.mass.sum() * G * dt
            np.testing.assert_allclose(vn[pushing], -contacts.gap[pushing] / dt, atol=VELOCITY_TOL)
            # Friction inside the disc.
            assert (np.hypot(lam[:, 1], lam[:, 2]) <= friction * lam[:, 0] * (1 + 1e-9) + 1e-12).all()
        # A v - b - J^T lambda over the free rows (a fixed node's velocity is prescribed, not
        # solved for): the sweeps' velocity error times A's largest row norm.
        free = ~system.prescribed
        residual = (system.matrix @ body.v.ravel() - system.rhs - impulse.ravel())[free]
        bound = VELOCITY_TOL * np.abs(system.matrix).sum(axis=1).max()
        assert np.abs(residual).max() <= bound
        checked += 1
    return checked


def test_a_resting_cube_carries_its_weight_without_sinking():
    body = _cube()
    scene = _scene(body)
    for _ in range(120):
        solution = scene.step(1.0 / 60.0)
    assert body.q[:, 2].min() > -1e-3
    # Static equilibrium: sum lambda_n = m g dt per step.
    carried = sum(i[:, 0].sum() for i in solution.impulses)
    assert carried == pytest.approx(body.mass.sum() * G / 60.0, rel=0.01)


def test_a_clamped_beam_settles_to_the_static_deflection():
    # Linear FEM (R = I), heavily damped: the end state solves K u = f_gravity (SciPy direct).
    material = Material(1e5, 0.3, 100.0, alpha=20.0, beta=0.0)
    body = _cube(cells=3, size=0.3, lift=0.0, material=material, fixed=lambda x: x[:, 0] < -0.149)
    body = FemBody(body.rest * [1.0, 0.5, 0.5], body.tets, material, fixed=body.fixed, corotational=False)
    scene = _scene(body, plane=False)
    for _ in range(400):
        scene.step(0.01)
    k = body.stiffness_matrix(body.rest).tocsc()
    free = np.repeat(~body.fixed, 3)
    f = (body.mass[:, None] * [0.0, 0.0, -G]).ravel()
    u = np.zeros(k.shape[0])
    u[free] = spla.spsolve(k[free][:, free], f[free])
    np.testing.assert_allclose((body.q - body.rest).ravel(), u, atol=2e-3 * np.abs(u).max())
    np.testing.assert_array_equal(body.q[body.fixed], body.rest[body.fixed])


def test_spectrum_bounds_enclose_the_dense_eigenvalues():
    body = _cube(cells=2)
    scene = _scene(body)
    scene.step(0.01)
    system = body.step_system(0.01, scene.gravity)
    a = system.matrix.toarray()
    d = np.zeros_like(a)
    for i in range(0, len(a), 3):
        d[i:i + 3, i:i + 3] = a[i:i + 3, i:i + 3]
    eig = np.sort(np.linalg.eigvals(np.linalg.solve(d, a)).real)
    lo, hi = spectrum(scene._stepper.model, scene._stepper.state)
    assert lo <= eig[0] and hi >= eig[-1]
    assert lo >= 0.5 * eig[0] and hi <= 1.05 * eig[-1]  # margins 0.8 / 1.02 plus Lanczos slack


def test_chebyshev_weights_tend_to_the_optimal_sor_factor():
    # omega_k -> 2 / (1 + sqrt(1 - rho^2)) (Golub and Van Loan 11.2.8), from 1 and 2 / (2 - rho^2).
    rho = 0.97
    w = chebyshev_weights(rho, 200)
    assert w[0] == 1.0 and w[1] == pytest.approx(2 / (2 - rho**2), rel=1e-14)
    assert w[-1] == pytest.approx(2 / (1 + np.sqrt(1 - rho**2)), rel=1e-12)


def test_warm_starts_survive_a_change_of_path():
    body = _cube()
    scene = _scene(body)
    for _ in range(40):
        scene.step(1.0 / 60.0)
    ids = {int(i) for c in scene.last_solution.contacts for i in c.ids}
    scene.node_arrays = False
    scene.step(1.0 / 60.0)  # the per-object path starts from the arrays' warm starts
    assert ids and set(scene._warm) <= ids | {int(i) for c in scene.last_solution.contacts for i in c.ids}
    assert scene.last_solution.iterations < 15  # warm: a cold start of this step takes ~25 sweeps


def test_a_diverging_node_is_reported_with_its_body_and_step():
    body = _cube(lift=0.5)
    scene = _scene(body)
    scene.step(0.01)
    body.v = np.where(np.arange(len(body.q))[:, None] == 7, np.nan, body.v)
    # The NaN spreads through A's blocks within the step; the report names the first node hit.
    with pytest.raises(SimulationError, match=r"cube: diverged at step 2 \(node \d+: NaN/inf\)"):
        scene.step(0.01)


def test_scenes_the_arrays_do_not_hold_step_per_object():
    body = _cube()
    scene = _scene(body)
    assert scene.path == "per object"  # nothing measured before the first step
    scene.step(0.01)
    assert scene.path.startswith("node arrays on cpu")  # (" (host copies)" under pytest --host-copies)
    assert node_model_supported(scene)
    scene.add_plane(Plane(point=(0.0, 0.0, -1.0)), adhesion=None)
    assert node_model_supported(scene)
    scene.add_plane(Plane(point=(0.0, 0.0, -2.0)), adhesion=Adhesion(stiffness=1e6, max_energy=1.0, viscosity=1e-3))
    assert node_model_supported(scene)  # adhesion is held (tests/contact/test_node_adhesion.py)
    scene.add_sphere(Sphere(center=(0.0, 0.0, -5.0)))
    assert node_model_supported(scene)  # statics in adhesive scenes too (tests/contact/test_node_static_adhesion.py)
    # Co-rotational and linear FEM bodies in one scene are not held.
    scene.add_body(FemBody(body.rest + (2.0, 0.0, 0.0), body.tets, body.material, corotational=False, name="linear"))
    assert not node_model_supported(scene)
    scene.step(0.01)
    assert scene._stepper is None and scene.path == "per object"
