"""Co-rotational FEM body against physics: free fall, rigid rotation, Euler-Bernoulli bending.

Tolerances: backward Euler is first order, so free fall is compared with its own closed form
(exact to round-off) and with the analytic parabola (error exactly g dt t / 2); bending is
compared with Euler-Bernoulli within 10 % (the issue's bound; linear tets are slightly stiff).
"""

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from scipy.spatial.transform import Rotation

from softvr.dynamics import FemBody, Material
from softvr.errors import InputError, SimulationError
from softvr.volume import Volume, grid_tet_mesh

G = np.array([0.0, 0.0, -9.81])


def box_mesh(size, cells):
    """Tet mesh of the box [0, size] with `cells` cubes per axis (5 tets each)."""
    size, cells = np.asarray(size, float), np.asarray(cells)
    spacing = size / cells
    return grid_tet_mesh(Volume(np.zeros(tuple(cells), np.uint8), spacing=spacing, origin=spacing / 2), tuple(cells))


def test_lumped_mass_is_the_total_mass():
    nodes, tets = box_mesh((0.2, 0.1, 0.1), (4, 2, 2))
    body = FemBody(nodes, tets, Material(1e5, 0.3, 1000.0))
    assert body.mass.sum() == pytest.approx(1000.0 * 0.2 * 0.1 * 0.1, rel=1e-12)


def test_free_fall_matches_backward_euler_and_the_parabola():
    """Rigid translation stores no elastic energy, so v_n = n g dt exactly and
    q_n = q_0 + g dt^2 n (n + 1) / 2 = q_0 + g t^2 / 2 + g dt t / 2 (first-order error)."""
    nodes, tets = box_mesh((0.1, 0.1, 0.1), (2, 2, 2))
    body = FemBody(nodes, tets, Material(1e5, 0.3, 1000.0))
    dt, n = 0.01, 50
    for _ in range(n):
        body.step(dt, gravity=G)
    t = n * dt
    # CG stops at a relative residual of 1e-8 of |b| ~ |M v|: velocities carry ~1e-8 |v|
    # (here |v| <= 5 m/s) per step, positions dt times the sum of those.
    np.testing.assert_allclose(body.v, np.broadcast_to(n * dt * G, body.v.shape), atol=1e-6)
    expected = nodes + G * (0.5 * t * t + 0.5 * dt * t)
    np.testing.assert_allclose(body.q, expected, atol=1e-6)
    assert np.abs(body.q - (nodes + 0.5 * G * t * t)).max() == pytest.approx(0.5 * 9.81 * dt * t, rel=1e-6)


def test_corotational_fem_has_no_spurious_forces_under_rigid_rotation():
    nodes, tets = box_mesh((0.3, 0.1, 0.1), (6, 2, 2))
    material = Material(1e6, 0.3, 1000.0)
    rot = Rotation.from_euler("zyx", [90, 30, -60], degrees=True).as_matrix()
    rotated = (nodes - nodes.mean(0)) @ rot.T + nodes.mean(0)
    corot = FemBody(nodes, tets, material)
    linear = FemBody(nodes, tets, material, corotational=False)
    # Scale: the force a 1 % stretch of the body would produce on a node.
    scale = material.young * 0.01 * 0.1 * 0.1
    assert np.abs(corot.elastic_forces(rotated)).max() < 1e-9 * scale
    assert np.abs(linear.elastic_forces(rotated)).max() > 10 * scale  # linear FEM: large ghost forces
    # A small stretch gives the same force in both formulations (they agree near rest).
    stretched = nodes * np.array([1.001, 1.0, 1.0])
    np.testing.assert_allclose(corot.elastic_forces(stretched), linear.elastic_forces(stretched),
                               atol=1e-3 * np.abs(linear.elastic_forces(stretched)).max())


@pytest.mark.parametrize("cells", [(60, 6, 6), (80, 8, 8)])
def test_cantilever_static_deflection_matches_euler_bernoulli(cells):
    """Tip load P on a clamped beam: delta = P L^3 / (3 E I), I = h^4 / 12 (slender: L = 10 h)."""
    length, h, young, load = 1.0, 0.1, 1e7, 1.0
    nodes, tets = box_mesh((length, h, h), cells)
    clamped = nodes[:, 0] < 1e-9
    body = FemBody(nodes, tets, Material(young, 0.0, 1000.0), fixed=clamped)
    tip = np.isclose(nodes[:, 0], length)
    f = np.zeros_like(nodes)
    f[tip, 2] = -load / tip.sum()
    free = ~np.repeat(clamped, 3)
    k = body.stiffness_matrix()
    u = np.zeros(k.shape[0])
    u[free] = spla.spsolve(k[free][:, free].tocsc(), f.ravel()[free])
    deflection = -u.reshape(-1, 3)[tip, 2].mean()
    expected = load * length**3 / (3 * young * h**4 / 12)
    assert deflection == pytest.approx(expected, rel=0.10)


def test_hanging_block_settles_to_the_static_solution_at_10ms_steps():
    """Stable at dt = 10 ms for stiff tissue (E = 1 MPa): a block clamped at its top, damped,
    settles to the static sag K u = M g."""
    nodes, tets = box_mesh((0.1, 0.1, 0.1), (3, 3, 3))
    top = np.isclose(nodes[:, 2], 0.1)
    body = FemBody(nodes, tets, Material(1e6, 0.3, 1000.0, alpha=20.0, beta=1e-3), fixed=top)
    for _ in range(200):
        body.step(0.01, gravity=G)
    free = ~np.repeat(top, 3)
    k = body.stiffness_matrix(nodes)
    u = np.zeros(k.shape[0])
    u[free] = spla.spsolve(k[free][:, free].tocsc(), (body.mass[:, None] * G).ravel()[free])
    np.testing.assert_allclose(body.q - nodes, u.reshape(-1, 3), atol=0.02 * np.abs(u).max())
    assert body.kinetic_energy() < 1e-9


def test_driven_end_face_stretches_a_bar_linearly():
    """Dirichlet nodes moving at ``fixed_velocity``: the end face of a bar clamped at x = 0 is
    pulled to x = L + d and held. With nu = 0 a uniaxial stretch has no lateral contraction,
    so the clamped faces constrain nothing more and the static solution is the linear field
    u_x = d x / L, u_y = u_z = 0, which linear tets reproduce exactly (the patch test). The
    driven nodes land on L + d to round-off (q += dt v); the rest settles to the line within
    the damped transient's residual (kinetic energy < 1e-12 J at the end)."""
    length, d = 0.2, 0.01
    nodes, tets = box_mesh((length, 0.05, 0.05), (8, 2, 2))
    clamp, end = np.isclose(nodes[:, 0], 0.0), np.isclose(nodes[:, 0], length)
    body = FemBody(nodes, tets, Material(1e5, 0.0, 1000.0, alpha=30.0), fixed=clamp | end)
    dt, ramp = 0.005, 20
    body.fixed_velocity[end, 0] = d / (ramp * dt)
    for n in range(400):
        if n == ramp:
            body.fixed_velocity[:] = 0.0
        body.step(dt, gravity=(0.0, 0.0, 0.0))
    np.testing.assert_allclose(body.q[end, 0], length + d, rtol=0, atol=1e-12)
    np.testing.assert_allclose(body.q[clamp], nodes[clamp], rtol=0, atol=0)
    expected = nodes.copy()
    expected[:, 0] *= 1.0 + d / length
    np.testing.assert_allclose(body.q, expected, atol=1e-3 * d)
    assert body.kinetic_energy() < 1e-12
    body.fixed_velocity = np.zeros((3, 3))
    with pytest.raises(InputError, match="fixed_velocity"):
        body.step(dt)


def test_bad_input_and_divergence_are_reported():
    nodes, tets = box_mesh((0.1, 0.1, 0.1), (1, 1, 1))
    for kwargs, field in (({"poisson": 0.5}, "poisson"), ({"young": 0.0}, "young"), ({"density": -1.0}, "density")):
        args = {"young": 1e5, "poisson": 0.3, "density": 1000.0} | kwargs
        with pytest.raises(InputError, match=f"Material.{field}"):
            Material(**args)
    material = Material(1e5, 0.3, 1000.0)
    with pytest.raises(InputError, match="inverted"):
        FemBody(nodes, tets[:, [0, 2, 1, 3]], material)
    with pytest.raises(InputError, match=r"per_tet_young\[2\]"):
        FemBody(nodes, tets, material, per_tet_young=[1e5, 1e5, -1.0, 1e5, 1e5])
    body = FemBody(nodes, tets, material, name="liver")
    body.step(0.01)
    body.v[3] = np.nan
    with pytest.raises(SimulationError, match="liver.*step 2"):
        body.step(0.01)


def test_element_rotations_are_the_polar_factors_and_k_is_the_force_jacobian():
    """R_e from the compiled svd3 equals SciPy's polar decomposition of F = Ds Dm^-1 (to
    round-off of float64 Jacobi sweeps), and K = sum R K_e R^T is the force Jacobian."""
    from scipy.linalg import polar

    nodes, tets = box_mesh((0.1, 0.1, 0.1), (2, 2, 2))
    body = FemBody(nodes, tets, Material(1e5, 0.3, 1000.0))
    rng = np.random.default_rng(4)
    rot = Rotation.from_euler("xyz", [40, -25, 70], degrees=True).as_matrix()
    q = nodes @ rot.T + 0.004 * rng.standard_normal(nodes.shape)
    r = body.rotations(q)
    x = q[tets]
    dm = (nodes[tets][:, 1:] - nodes[tets][:, :1]).transpose(0, 2, 1)
    f = (x[:, 1:] - x[:, :1]).transpose(0, 2, 1) @ np.linalg.inv(dm)
    expected = np.stack([polar(fe)[0] for fe in f])
    np.testing.assert_allclose(r, expected, atol=1e-9)
    # At a rigidly rotated (stress-free) state the co-rotational tangent has no rotation-change
    # term, so K = -df/dq exactly; central differences are exact for the quadratic part and
    # leave O(eps^2) of the rest.
    rigid = nodes @ rot.T
    k = body.stiffness_matrix(rigid).toarray()
    np.testing.assert_allclose(k, k.T, atol=1e-9 * np.abs(k).max())
    direction = rng.standard_normal(q.size)
    eps = 1e-6
    df = (body.elastic_forces(rigid + eps * direction.reshape(q.shape))
          - body.elastic_forces(rigid - eps * direction.reshape(q.shape))).ravel() / (2 * eps)
    np.testing.assert_allclose(-df, k @ direction, atol=1e-6 * np.abs(k @ direction).max())


def test_compliance_is_the_block_of_the_inverse_step_matrix():
    """``compliance(blocks)`` (trailing corner of a reordered LU) equals rows / columns of the
    dense inverse of A = M + dt (alpha M + beta K) + dt^2 K; fixed nodes give zero rows."""
    nodes, tets = box_mesh((0.1, 0.1, 0.1), (2, 2, 2))
    fixed = nodes[:, 2] < 1e-9
    body = FemBody(nodes, tets, Material(1e5, 0.3, 1000.0, alpha=1.0, beta=1e-3), fixed=fixed)
    body.q = body.q + 0.003 * np.random.default_rng(1).standard_normal(body.q.shape) * ~fixed[:, None]
    dt = 0.01
    body.unconstrained_velocity(dt)
    k = body.stiffness_matrix().toarray()
    m = np.repeat(body.mass, 3)
    a = np.diag(m * (1 + dt * 1.0)) + (dt * 1e-3 + dt * dt) * k
    free = ~np.repeat(fixed, 3)
    inverse = np.zeros_like(a)
    inverse[np.ix_(free, free)] = np.linalg.inv(a[np.ix_(free, free)])
    blocks = np.array([0, 5, np.flatnonzero(fixed)[1], len(nodes) - 1, 13])
    dofs = (3 * blocks[:, None] + np.arange(3)).ravel()
    w = body.compliance(blocks)
    np.testing.assert_allclose(w, inverse[np.ix_(dofs, dofs)], atol=1e-10 * np.abs(inverse).max())
    assert not w[6:9].any() and not w[:, 6:9].any()
    with pytest.raises(InputError, match="distinct node indices"):
        body.compliance([0, 5, 5])
    # The same factorization serves solve(): A^-1 rhs exact to round-off.
    rhs = np.random.default_rng(2).standard_normal(body.v.shape)
    np.testing.assert_allclose(body.solve(rhs).ravel(), inverse @ rhs.ravel(), atol=1e-10 * np.abs(inverse @ rhs.ravel()).max())
