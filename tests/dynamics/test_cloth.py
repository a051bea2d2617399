"""Mass-spring cloth against physics: mass, free fall, static sag of a hanging strip, energy decay.

Tolerances: backward Euler is first order, so free fall is compared with its own closed form
(exact to the CG tolerance) and with the analytic parabola (error exactly g dt t / 2); the hanging
strip is compared with a chain of springs in series within 3 % (derived in its test); the swinging
cloth's energy may rise in a step by at most the exact third-order Taylor remainder of the spring
energy plus the CG residual's work (derived in its test).
"""

import numpy as np
import pytest

from softvr.dynamics.cloth import ClothBody, grid_triangle_mesh
from softvr.errors import InputError, SimulationError

G = np.array([0.0, 0.0, -9.81])


def test_lumped_mass_is_density_times_area():
    # A tilted, non-square grid: the area is width * height whatever the orientation.
    cloth = ClothBody.grid(0.6, 0.4, 6, 3, density=0.3, stretch=100.0, u_axis=(1, 1, 0), v_axis=(-1, 1, 1))
    assert cloth.mass.sum() == pytest.approx(0.3 * 0.6 * 0.4, rel=1e-12)
    assert cloth.area.sum() == pytest.approx(0.6 * 0.4, rel=1e-12)


def test_grid_springs_are_edges_quad_diagonals_and_bend_springs():
    nx, ny = 4, 3
    cloth = ClothBody.grid(0.4, 0.3, nx, ny, density=0.1, stretch=100.0, shear=10.0, bend=1.0)
    kinds = {kind: int((cloth.spring_kind == kind).sum()) for kind in ("stretch", "shear", "bend")}
    # Sides of all quads counted once, plus one triangulating diagonal per quad.
    assert kinds["stretch"] == nx * (ny + 1) + ny * (nx + 1) + nx * ny
    assert kinds["shear"] == nx * ny  # the other diagonal of every quad
    assert kinds["bend"] == (nx - 1) * ny + (ny - 1) * nx  # one across every interior grid line
    np.testing.assert_allclose(cloth.rest_length[cloth.spring_kind == "shear"], np.hypot(0.1, 0.1))
    np.testing.assert_allclose(cloth.rest_length[cloth.spring_kind == "bend"], np.hypot(0.1, 0.2))
    assert set(np.unique(cloth.spring_stiffness)) == {100.0, 10.0, 1.0}
    # A closed tetrahedron surface: vertices opposite an edge are joined by an edge already.
    tetra = ClothBody(np.eye(4, 3), [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], density=1.0, stretch=1.0,
                      shear=1.0, bend=1.0)
    assert len(tetra.springs) == 6 and set(tetra.spring_kind) == {"stretch"}


def test_stiffness_matrix_is_the_force_jacobian_and_clamped_under_compression():
    rng = np.random.default_rng(1)
    vertices, triangles = grid_triangle_mesh(0.3, 0.2, 3, 2)
    cloth = ClothBody(vertices, triangles, density=0.1, stretch=200.0, shear=50.0, bend=5.0)

    def fd_jacobian(q, eps):
        jac = np.zeros((q.size, q.size))
        for c in range(q.size):
            dq = np.zeros(q.size)
            dq[c] = eps
            jac[:, c] = (cloth.elastic_forces(q + dq.reshape(q.shape))
                         - cloth.elastic_forces(q - dq.reshape(q.shape))).ravel() / (2 * eps)
        return jac

    # Every spring stretched by 10-20 % (uniform scaling plus a small out-of-plane wrinkle).
    stretched = vertices * 1.15 + rng.normal(scale=0.002, size=vertices.shape)
    lengths = np.linalg.norm(stretched[cloth.springs[:, 0]] - stretched[cloth.springs[:, 1]], axis=1)
    assert (lengths > cloth.rest_length).all()
    # Central differences: truncation ~ eps^2 k / L^2, round-off ~ 1e-16 |f| / eps; both << 1e-6 k.
    eps = 1e-6
    np.testing.assert_allclose(-cloth.stiffness_matrix(stretched).toarray(), fd_jacobian(stretched, eps),
                               atol=1e-6 * 200.0)
    # Compressed by 20 %: the exact Jacobian is indefinite (sideways buckling), the clamped K is not.
    compressed = vertices * 0.8 + rng.normal(scale=0.002, size=vertices.shape)
    exact = -fd_jacobian(compressed, eps)
    assert np.linalg.eigvalsh(0.5 * (exact + exact.T)).min() < -1.0
    assert np.linalg.eigvalsh(cloth.stiffness_matrix(compressed).toarray()).min() > -1e-9 * 200.0


def test_free_fall_matches_backward_euler_and_the_parabola():
    """Rigid translation stretches no spring and has no relative velocity, so v_n = n g dt exactly
    and q_n = q_0 + g dt^2 n (n + 1) / 2 = q_0 + g t^2 / 2 + g dt t / 2 (first-order error)."""
    cloth = ClothBody.grid(0.3, 0.2, 6, 4, density=0.2, stretch=500.0, shear=50.0, bend=5.0, damping=0.1,
                           u_axis=(1, 0, 1), v_axis=(0, 1, 0))
    start = cloth.q.copy()
    dt, n = 0.01, 50
    for _ in range(n):
        cloth.step(dt, gravity=G)
    t = n * dt
    # CG stops at a relative residual of 1e-8 of |b| ~ |M v|: velocities carry ~1e-8 |v|
    # (here |v| <= 5 m/s) per step, positions dt times the sum of those.
    np.testing.assert_allclose(cloth.v, np.broadcast_to(n * dt * G, cloth.v.shape), atol=1e-6)
    np.testing.assert_allclose(cloth.q, start + G * (0.5 * t * t + 0.5 * dt * t), atol=1e-6)
    # The first-order error of backward Euler against the parabola, to the same CG tolerance.
    assert np.abs(cloth.q - (start + 0.5 * G * t * t)).max() == pytest.approx(0.5 * 9.81 * dt * t, abs=1e-6)


def test_solve_applies_the_inverse_of_the_step_matrix():
    cloth = ClothBody.grid(0.2, 0.2, 4, 4, density=0.2, stretch=300.0, shear=30.0, bend=3.0, damping=0.05)
    cloth.q = cloth.q * 1.02  # stretched: spring forces act
    cloth.v = np.random.default_rng(2).normal(scale=0.1, size=cloth.v.shape)
    # Two CG solves from different starts agree to ~cond(A) x the relative residual; a residual
    # of 1e-12 (cond(A) ~ 1 + dt^2 k / m ~ 1e3 here) makes that < 1e-9 |v|.
    cloth.cg_tolerance = 1e-12
    dt = 0.01
    v1 = cloth.unconstrained_velocity(dt, gravity=G)
    b = cloth.mass[:, None] * cloth.v + dt * (cloth.elastic_forces() + cloth.mass[:, None] * G)
    np.testing.assert_allclose(cloth.solve(b), v1, atol=1e-7 * np.abs(v1).max())
    # Linear: A^-1 (2 b) = 2 A^-1 b.
    np.testing.assert_allclose(cloth.solve(2 * b), 2 * v1, atol=1e-7 * np.abs(v1).max())


def test_hanging_strip_settles_to_the_chain_of_springs_in_series():
    """A 1 x N ladder of square cells (side h), clamped along its top, hanging under gravity.

    Each cell holds two rails and one rung (stretch k, length h), its triangulating diagonal
    (stretch k) and its other diagonal (shear, set to k too; bend springs off), so each cell is
    mirror symmetric. Stretching a cell by delta while its lower rung narrows by chi lengthens the
    rails by delta, the diagonals by (delta - chi) / sqrt(2) and shortens the rung by chi:

        U = k delta^2 + k (delta - chi)^2 / 2 + k chi^2 / 2,

    minimal at chi = delta / 2, U = (5/4) k delta^2: the cell is a spring of k_cell = 5 k / 2.
    Cells are springs in series; the cell below row r carries the weight of rows 0..r. With
    lumped masses the end rows weigh rho w h / 2 and the others rho w h, so

        delta_r = g sum_{i <= r} m_i / k_cell,    u_r = sum_{i >= r} delta_i   (row r from the bottom).

    The clamp keeps the top rung from narrowing (chi = 0 there: k_cell = 3 k at the clamp), which
    stiffens the top cells: the simulated sag lies between the 3 k and 5 k / 2 chains, within
    3 % of the latter (the boundary layer is a couple of cells; strains are ~1 % so geometric
    nonlinearity is smaller still).
    """
    n, h, rho, k = 10, 0.05, 0.5, 40.0
    cloth = ClothBody.grid(h, n * h, 1, n, u_axis=(1, 0, 0), v_axis=(0, 0, 1), density=rho, stretch=k, shear=k,
                           bend=0.0, damping=0.5, alpha=2.0, name="strip")
    cloth.fixed = np.isclose(cloth.rest[:, 2], n * h)
    for _ in range(300):  # 3 s at 10 ms: stable although dt sqrt(k / m) ~ 1
        cloth.step(0.01, gravity=G)
    assert cloth.kinetic_energy() < 1e-9  # settled
    m_row = np.full(n + 1, rho * h * h)
    m_row[[0, n]] /= 2
    load = 9.81 * np.cumsum(m_row)[:n]  # [N] carried by the cell above row r

    def chain(k_cell):
        delta = load / k_cell
        return np.array([delta[r:].sum() for r in range(n + 1)])

    sag = -(cloth.q - cloth.rest)[:, 2].reshape(n + 1, 2).mean(axis=1)  # per row, from the bottom
    series = chain(2.5 * k)
    np.testing.assert_allclose(sag, series, atol=0.03 * series.max())
    assert chain(3.0 * k)[0] < sag[0] < series[0]
    assert series[0] / (n * h) > 0.005  # a real stretch, not a rounding-level one


def test_pinned_cloth_swings_without_gaining_energy():
    """Linearized backward Euler, per step (K_c the clamped stiffness, H the exact spring Hessian,
    D the damping matrix, r = b - A v1 the CG residual, dq = dt v1):

        dE = -1/2 |dv|_M^2 - dt v1.D v1 - 1/2 dq.K_c dq - 1/2 dq.(K_c - H) dq + R + v1.r

    with R the third-order Taylor remainder of the spring energy from q0 to q1. K_c and K_c - H are
    positive semi-definite (the clamp only drops the negative part), so dE <= R + |v1| |r|.
    The test computes R exactly, per spring, with its own spring formulas, and bounds |r| by the
    CG tolerance times |b| (10x margin for the recurrence residual). Over the whole swing the
    scheme dissipates: the energy ends well below where it started.
    """
    nx = 10
    cloth = ClothBody.grid(0.5, 0.5, nx, nx, density=0.2, stretch=1000.0, shear=100.0, bend=10.0, name="flag")
    cloth.fixed = np.isin(np.arange(len(cloth.rest)), [0, nx])  # the two corners of one edge
    k, rest_length = cloth.spring_stiffness, cloth.rest_length
    i, j = cloth.springs.T

    def energy(q, v):
        lengths = np.linalg.norm(q[i] - q[j], axis=1)
        return (0.5 * np.sum(cloth.mass[:, None] * v**2) - np.sum(cloth.mass * (q @ G))
                + 0.5 * np.sum(k * (lengths - rest_length) ** 2))

    dt = 1 / 60
    e_start = energy(cloth.q, cloth.v)
    lowest = 0.0
    for _ in range(120):  # 2 s
        q0, v0, e0 = cloth.q.copy(), cloth.v.copy(), energy(cloth.q, cloth.v)
        b = cloth.mass[:, None] * v0 + dt * (cloth.elastic_forces() + cloth.mass[:, None] * G)
        cloth.step(dt, gravity=G)
        d0, d1 = q0[i] - q0[j], cloth.q[i] - cloth.q[j]
        step = d1 - d0
        l0 = np.linalg.norm(d0, axis=1)
        s = np.einsum("si,si->s", d0 / l0[:, None], step)
        step2 = np.einsum("si,si->s", step, step)
        # U(d1) - U(d0) - grad U . step - 1/2 step.H.step, H = k [I - (L / l) (I - d^ d^T)].
        remainder = np.sum(0.5 * k * (np.linalg.norm(d1, axis=1) - rest_length) ** 2
                           - 0.5 * k * (l0 - rest_length) ** 2 - k * (l0 - rest_length) * s
                           - 0.5 * k * (step2 - rest_length / l0 * (step2 - s * s)))
        residual_work = 10 * cloth.cg_tolerance * np.linalg.norm(cloth.v) * np.linalg.norm(b)
        assert energy(cloth.q, cloth.v) - e0 <= remainder + residual_work
        lowest = min(lowest, cloth.q[:, 2].min())
    assert np.isfinite(cloth.q).all() and (cloth.q[cloth.fixed] == cloth.rest[cloth.fixed]).all()
    assert lowest < -0.4  # it did swing down, hanging from its pinned edge (0.5 m long)
    # Stretching a spring by 5 % takes k 0.05 L = 2.5 N, five times the cloth's weight (0.49 N).
    lengths = np.linalg.norm(cloth.q[i] - cloth.q[j], axis=1)
    assert (lengths < 1.05 * rest_length).all()
    # Dissipation: the cloth falls ~0.25 m on average (mg ~ 0.5 N: ~0.12 J released); backward
    # Euler keeps a good part of it off the books (exact dynamics would conserve E).
    assert energy(cloth.q, cloth.v) < e_start - 0.05


def test_bad_input_and_divergence_are_reported():
    vertices, triangles = grid_triangle_mesh(0.1, 0.1, 2, 2)
    args = {"density": 0.1, "stretch": 100.0, "shear": 10.0, "bend": 1.0}
    collinear = vertices.copy()
    collinear[[0, 1, 4], 1] = 0.0
    collinear[4, 0] = 0.025  # vertex 4 onto the line through 0 and 1: triangle 0 = (0, 1, 4) is flat
    with pytest.raises(InputError, match=r"triangles\[0\].*degenerate"):
        ClothBody(collinear, triangles, **args)
    with pytest.raises(InputError, match=r"triangles\[3\].*degenerate"):
        ClothBody(vertices, np.vstack([triangles[:3], [[2, 2, 5]], triangles[4:]]), **args)
    with pytest.raises(InputError, match=r"triangles\[5\]"):
        ClothBody(vertices, np.vstack([triangles[:5], [[0, 1, 9]], triangles[6:]]), **args)
    with pytest.raises(InputError, match=r"triangles\[6\].*repeat of triangles\[2\]"):
        ClothBody(vertices, np.vstack([triangles[:6], triangles[2, ::-1][None], triangles[7:]]), **args)
    with pytest.raises(InputError, match=r"vertices\[9\].*unused"):
        ClothBody(np.vstack([vertices, [[1.0, 1.0, 1.0]]]), triangles, **args)
    bad = vertices.copy()
    bad[7, 2] = np.nan
    with pytest.raises(InputError, match=r"vertices\[7\]"):
        ClothBody(bad, triangles, **args)
    for field in ("stretch", "shear", "bend", "density", "damping"):
        with pytest.raises(InputError, match=field):
            ClothBody(vertices, triangles, **(args | {field: -1.0}))
    for field in ("stretch", "density"):
        with pytest.raises(InputError, match=field):
            ClothBody(vertices, triangles, **(args | {field: 0.0}))
    with pytest.raises(InputError, match="nx"):
        ClothBody.grid(1.0, 1.0, 0, 2, **args)

    cloth = ClothBody(vertices, triangles, **args, name="sail")
    cloth.step(0.01)
    cloth.v[3] = np.nan
    with pytest.raises(SimulationError, match=r"sail.*step 2.*vertex 3"):
        cloth.step(0.01)
    cloth = ClothBody(vertices, triangles, **args, name="sail")
    cloth.step(0.01)
    cloth.step(0.01)
    with pytest.raises(SimulationError, match=r"sail.*step 3.*speed"):
        cloth.integrate(np.full(cloth.v.shape, 1e6), 0.01)
    assert cloth.step_count == 2
