"""Mass-spring cloth (:class:`softvr.dynamics.ClothBody`) on the whole-scene node arrays: its
vertices are free nodes, its springs blocks of ``A`` (thesis eq. 5.2, the springs linearized at
the step's start), swept with the contacts (eqs. 5.5-5.6).

Held to independent truths: a step equals SciPy's direct solve of eq. 5.2 assembled here from
the spring law; a cloth hanging from its top edge settles where scipy.optimize finds the minimum
of its potential energy; a cloth dropped on a sphere solves eq. 5.5 every step, rests on the
sphere without entering it and is carried by it. Tolerances come from the sweeps' stopping rule
(SWEEP_TOLERANCE = 1e-5 m/s on the velocities, 3x allowed).
"""

import numpy as np
import pytest
import scipy.optimize as so
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from softvr import Scene
from softvr.collision import Sphere
from softvr.dynamics import ClothBody, EmbeddedPoints
from softvr.scene import bundled, load_scene
from softvr.sim import node_model_supported
from softvr.sim._node_step import SWEEP_TOLERANCE

G = 9.81
VELOCITY_TOL = 3 * SWEEP_TOLERANCE  # [m/s]
GRAVITY = np.array([0.0, 0.0, -G])


def _add_cloth(scene, cloth):
    n = len(cloth.q)
    scene.add_body(cloth, collision_points=EmbeddedPoints(cloth, np.arange(n)[:, None], np.ones((n, 1))),
                   collision_triangles=cloth.triangles)
    return cloth


def _hanging(nx=4, **kwargs):
    """A 0.2 m square sheet in the x-z plane, its top edge (z = 0) pinned."""
    cloth = ClothBody.grid(0.2, 0.2, nx, nx, origin=(0.0, 0.0, -0.2), u_axis=(1.0, 0.0, 0.0),
                           v_axis=(0.0, 0.0, 1.0), **kwargs)
    cloth.fixed[:] = cloth.q[:, 2] > -1e-9
    return cloth


def _system(cloth, dt):
    """``A`` [3n, 3n] and ``b`` [3n] of eq. 5.2 for the cloth at its current state, written out
    from the spring law (module doc of softvr.dynamics.cloth): per spring, d = q_i - q_j,
    u = d / |d|, f_i = -k (|d| - L) u, and the block S = dt^2 k [max(0, 1 - L/|d|) (I - u u^T)
    + u u^T] + dt c u u^T added to A_ii, A_jj and subtracted from A_ij, A_ji;
    A += M (1 + dt alpha), b = M v + dt (f + M g)."""
    n = len(cloth.q)
    i, j = cloth.springs[:, 0], cloth.springs[:, 1]
    k, rest = cloth.spring_stiffness[:, None, None], cloth.rest_length
    d = cloth.q[i] - cloth.q[j]
    length = np.linalg.norm(d, axis=1)
    u = d / length[:, None]
    uu = u[:, :, None] * u[:, None, :]
    transverse = np.maximum(0.0, 1.0 - rest / length)[:, None, None]
    s = dt * dt * k * (transverse * (np.eye(3) - uu) + uu) + dt * cloth.damping * uu
    dof = np.arange(3)
    rows, cols, vals = [], [], []
    for r, c, sign in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
        rows.append(np.broadcast_to((3 * r[:, None] + dof)[:, :, None], s.shape).ravel())
        cols.append(np.broadcast_to((3 * c[:, None] + dof)[:, None, :], s.shape).ravel())
        vals.append(sign * s.ravel())
    a = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n))
    a = a + sp.diags(np.repeat(cloth.mass * (1.0 + dt * cloth.alpha), 3))
    f = -cloth.spring_stiffness[:, None] * (length - rest)[:, None] * u
    force = np.zeros((n, 3))
    np.add.at(force, i, f)
    np.add.at(force, j, -f)
    b = (cloth.mass[:, None] * (cloth.v + dt * GRAVITY) + dt * force).ravel()
    return a.tocsr(), b


def test_a_cloth_step_equals_scipys_direct_solve_of_eq_5_2():
    """A pinned sheet pulled out of shape (some springs stretched, some compressed: the clamp
    of the transverse term acts) and moving: one step on the arrays equals SciPy's solve of
    eq. 5.2 over the free vertices, the pinned ones at their prescribed velocity, within the
    sweeps' tolerance."""
    cloth = _hanging(stretch=50.0, shear=5.0, bend=0.5, density=0.5, damping=0.02, alpha=0.3)
    rng = np.random.default_rng(1)
    free = ~cloth.fixed
    cloth.q[free] += rng.normal(scale=0.01, size=(int(free.sum()), 3))
    cloth.v[free] = rng.normal(scale=0.1, size=(int(free.sum()), 3))
    cloth.fixed_velocity[cloth.fixed] = (0.02, 0.0, 0.01)
    scene = Scene(gravity=tuple(GRAVITY))
    _add_cloth(scene, cloth)
    assert node_model_supported(scene)
    dt = 0.01
    a, b = _system(cloth, dt)
    dof = np.repeat(free, 3)
    known = np.where(dof, 0.0, cloth.fixed_velocity.ravel())
    v = known.copy()
    v[dof] = spla.spsolve(a[dof][:, dof].tocsc(), b[dof] - a[dof] @ known)
    scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    np.testing.assert_allclose(cloth.v.ravel(), v, rtol=0, atol=VELOCITY_TOL)


def test_a_hanging_cloth_settles_at_scipys_minimum_of_its_potential_energy():
    """Pinned along its top edge, a sheet stretches under its weight to where its potential
    sum 1/2 k (l - L)^2 - sum m g . q is least (scipy.optimize, the pinned vertices held).
    Tolerance: at rest the sweeps leave a velocity error e of VELOCITY_TOL, a force m e / dt =
    3.75e-6 N on a vertex (m <= 1.25 g), which the chain of 4 springs (k = 5 N/m each) to the
    pinned edge balances within 4 m e / (dt k) = 3e-6 m."""
    cloth = _hanging(stretch=5.0, shear=0.5, bend=0.05, density=0.5, damping=0.05, alpha=5.0)
    assert cloth.mass.max() == pytest.approx(1.25e-3) and len(cloth.q) == 25
    scene = Scene(gravity=tuple(GRAVITY))
    _add_cloth(scene, cloth)
    free = ~cloth.fixed
    start = cloth.q.copy()

    def energy(x):
        q = start.copy()
        q[free] = x.reshape(-1, 3)
        return cloth.potential_energy(tuple(GRAVITY), q)

    def gradient(x):
        q = start.copy()
        q[free] = x.reshape(-1, 3)
        return -(cloth.elastic_forces(q) + cloth.mass[:, None] * GRAVITY)[free].ravel()

    best = so.minimize(energy, start[free].ravel(), jac=gradient, method="BFGS", options={"gtol": 1e-12})
    assert np.abs(gradient(best.x)).max() < 1e-9  # [N] a minimum to round-off
    target = best.x.reshape(-1, 3)
    assert np.abs(target - start[free]).max() > 0.01  # a visible sag (1.3 cm)
    for _ in range(300):
        scene.step(0.01)
    assert type(scene._stepper).__name__ == "NodeStepper"
    assert np.abs(cloth.v).max() < VELOCITY_TOL
    np.testing.assert_allclose(cloth.q[free], target, rtol=0, atol=3e-6)
    np.testing.assert_array_equal(cloth.q[cloth.fixed], start[cloth.fixed])


def _check_eq_5_5(cloth, a, b, solution, dt, mu, centre=None, x0=None):
    """One step's eq. 5.5 for the cloth's contacts (one vertex each), from ``a``, ``b`` of
    :func:`_system` at the step's start: A v = b + J^T lambda (J^T lambda: each contact's world
    impulse on its vertex) within VELOCITY_TOL times A's largest row sum, lambda_n >= 0,
    n . v >= -gap / dt with equality where the contact pushes, friction within mu lambda_n;
    with ``centre`` [m], the normals along the radius from it through the vertex at ``x0``.
    Returns the impulses summed per vertex [n, 3] [N s]."""
    total = cloth.mass.sum()
    impulse = np.zeros_like(cloth.v)
    for contacts, lam, frames in zip(solution.contacts, solution.impulses, solution.frames):
        nodes = contacts.a.blocks[:, 0]
        world = np.einsum("ci,cij->cj", lam, frames)
        np.add.at(impulse, nodes, world)
        if centre is not None:
            d = (x0[nodes] - centre) / np.linalg.norm(x0[nodes] - centre, axis=1)[:, None]
            np.testing.assert_allclose(contacts.normal, d, atol=1e-12)
        vn = np.einsum("cj,cj->c", cloth.v[nodes], contacts.normal)
        assert (lam[:, 0] >= 0).all()
        assert (vn >= -contacts.gap / dt - VELOCITY_TOL).all()
        pushing = lam[:, 0] > 1e-6 * total * G * dt
        np.testing.assert_allclose(vn[pushing], -contacts.gap[pushing] / dt, atol=VELOCITY_TOL)
        assert (np.hypot(lam[:, 1], lam[:, 2]) <= mu * lam[:, 0] * (1 + 1e-9) + 1e-12).all()
    residual = a @ cloth.v.ravel() - b - impulse.ravel()
    assert np.abs(residual).max() <= VELOCITY_TOL * np.abs(a).sum(axis=1).max()
    return impulse


def test_a_cloth_on_a_sphere_solves_eq_5_5_every_step_and_rests_on_it():
    """A 0.2 m sheet dropped 5 mm onto a sphere of radius 0.25 m (the scene's second sphere):
    every step A v = b + J^T lambda (J^T lambda: each contact's world impulse on its vertex),
    lambda_n >= 0, the normal velocity n . v >= -gap / dt with equality where the contact
    pushes, friction within mu lambda_n, contacts along the radius through the vertex; at rest
    no vertex inside the sphere by more than a step's travel at the tolerance and the sphere
    carries the weight (sum of world impulses / dt = M g within M VELOCITY_TOL / dt)."""
    mu, dt, radius = 0.5, 0.01, 0.25
    scene = Scene(gravity=tuple(GRAVITY), friction=mu)
    scene.add_sphere(Sphere(center=(3.0, 0.0, 0.0), radius=0.1))
    scene.add_sphere(Sphere(center=(0.0, 0.0, 0.0), radius=radius, friction=mu))
    cloth = _add_cloth(scene, ClothBody.grid(0.2, 0.2, 6, 6, origin=(-0.1, -0.1, radius + 0.005), density=0.5,
                                             stretch=50.0, shear=5.0, bend=0.5, damping=0.05, alpha=3.0))
    total = cloth.mass.sum()
    for _ in range(150):
        a, b = _system(cloth, dt)
        x0 = cloth.q.copy()
        solution = scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper"
        impulse = _check_eq_5_5(cloth, a, b, solution, dt, mu, centre=np.zeros(3), x0=x0)
    gap = np.linalg.norm(cloth.q, axis=1) - radius
    assert gap.min() >= -VELOCITY_TOL * dt
    assert np.abs(cloth.v).max() < 1e-3
    force = impulse.sum(axis=0) / dt
    np.testing.assert_allclose(force, [0.0, 0.0, total * G], atol=total * VELOCITY_TOL / dt)


@pytest.mark.parametrize("name", ["cloth-sphere.toml", "cloth-wall.toml"])
def test_bundled_cloth_scenes_step_on_the_node_arrays(name):
    player = load_scene(bundled(name))
    assert node_model_supported(player.scene)
    player.scene.step(player.dt)
    assert type(player.scene._stepper).__name__ == "NodeStepper"


def test_the_bundled_draped_cloth_converges_every_step_and_solves_eq_5_5():
    """cloth-sphere.toml (a 1 m sheet of 21 x 21 vertices, dt^2 k / m = 111 at dt = 1/60 s,
    friction 0.5 on a sphere and the ground) for 60 steps, past the drape (from about its 37th
    step ~100 frictional contacts, most sliding): every step's sweeps stop on their tolerance
    (eqs. 5.5-5.6: velocities within SWEEP_TOLERANCE), before a cap of 300 sweeps (the
    converged steps take at most ~200), and its solution meets eq. 5.5 with A and b written out
    from the spring law (:func:`_check_eq_5_5`)."""
    player = load_scene(bundled("cloth-sphere.toml"))
    scene, dt, cloth = player.scene, player.dt, player.bodies["cloth"]
    scene.pgs_iterations = 300
    for _ in range(60):
        a, b = _system(cloth, dt)
        solution = scene.step(dt)
        assert solution.iterations < scene.pgs_iterations
        _check_eq_5_5(cloth, a, b, solution, dt, 0.5)
