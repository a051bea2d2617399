"""Multicolour symmetric block Gauss-Seidel sweeps of eq. 5.6 on the node arrays
(softvr.contact.node_colouring, node_gauss_seidel; NodeSolve(colours=...)), held to the block
pattern of A, to SciPy's direct solve of eq. 5.2, to the MLCP of eq. 5.5 and to the spectral
radius of the symmetric Gauss-Seidel iteration matrix computed densely by NumPy.

Tolerances: the sweeps stop at an estimated velocity error of SWEEP_TOLERANCE (1e-5 m/s) from
a geometric tail, so velocities are held to 3x that (as in tests/sim/test_node_arrays.py).
"""

import numpy as np
import pytest
import scipy.optimize as so
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp
from scipy.spatial.transform import Rotation

from softvr import Scene
from softvr.collision import Plane
from softvr.contact.node_colouring import colour_nodes
from softvr.contact.node_factored import free_matrix
from softvr.contact import node_gauss_seidel
from softvr.contact.node_gauss_seidel import GaussSeidelSweep, gauss_seidel_spectrum
from softvr.contact.node_jacobi import NodeSolve
from softvr.dynamics import Coupling, EmbeddedPoints, FixedBody, Material, RigidBody, RigidPoints
from softvr.scene import bundled, load_scene
from softvr.sim import _node_step, _node_sweeps
from softvr.sim._node_step import SPECTRUM_MARGIN, SWEEP_TOLERANCE, NodeStepper, spectrum
from softvr.sim._node_sweeps import sweeps_per_decade

from tests.sim.test_node_arrays import VELOCITY_TOL, _cube, _scene, _solve_step, check_mlcp_steps
from tests.sim.test_node_rigid import _rigid_box
from tests.sim.test_node_rigid_couplings import G, _block, _box_system
from tests.sim.test_node_surfaces import _add_with_surface
from tests.sim.test_node_surfaces import _block as _surface_block


def _stiff_block(lift=0.5, cells=4):
    """A clamped block (bottom face fixed) whose tets alternate between 1e5 and 1e9 Pa: stiff
    and heterogeneous, as the head CT's bone and tissue."""
    body = _cube(cells=cells, lift=lift, material=Material(1e5, 0.3, 1000.0, alpha=0.0, beta=1e-3),
                 fixed=lambda nodes: nodes[:, 2] < nodes[:, 2].min() + 1e-9)
    young = np.where(np.arange(len(body.tets)) % 3 == 0, 1e9, 1e5)
    return type(body)(body.rest, body.tets, body.material, per_tet_young=young, fixed=body.fixed, name="block")


def _prepared(body, dt, plane=False):
    """A stepper with this step's A, b assembled (and contacts detected)."""
    scene = _scene(body, plane=plane)
    stepper = NodeStepper(scene)
    stepper._record(dt)
    for replay in stepper._recorded[1:5]:
        replay()
    return scene, stepper


def _gauss_seidel(stepper, dt, max_sweeps=500):
    m = stepper.model
    colours = colour_nodes(m.row_start.numpy(), m.block_col.numpy())
    a, free = free_matrix(m, stepper.state)
    index = np.cumsum(free) - 1
    lo, hi = gauss_seidel_spectrum(a, index[colours.order[free[colours.order]]])
    bounds = (lo * SPECTRUM_MARGIN[0], hi * SPECTRUM_MARGIN[1])
    omega = 1.0 / spectrum(m, stepper.state)[1]
    return NodeSolve(m, stepper.state, dt, bounds, max_sweeps=max_sweeps, colours=colours, omega=omega), colours, bounds


def _start(stepper, v):
    for buffer in (stepper.state.sweep_buffers[0], stepper.state.sweep_buffers[2]):
        buffer.numpy()[:] = v


def test_no_block_of_a_couples_two_nodes_of_one_colour():
    # Checked on A as SciPy assembles it from the body (eq. 5.2), not on the arrays' pattern.
    body = _stiff_block()
    scene, stepper = _prepared(body, 0.01)
    colours = colour_nodes(stepper.model.row_start.numpy(), stepper.model.block_col.numpy())
    coo = sp.coo_matrix(body.step_system(0.01, scene.gravity).matrix)
    rows, cols = coo.row // 3, coo.col // 3
    coupled = (rows != cols) & (coo.data != 0)
    assert coupled.sum() > 10 * len(body.q)  # the check has blocks to look at
    assert not (colours.colour[rows[coupled]] == colours.colour[cols[coupled]]).any()
    assert sorted(colours.order) == list(range(len(body.q)))
    assert 2 <= colours.count <= 27  # a grid tet mesh: at most its 27-node stencil


def test_sweeps_without_contacts_land_on_scipy_direct_solve_of_eq_5_2():
    body = _stiff_block()
    rng = np.random.default_rng(1)
    body.v = 0.05 * rng.standard_normal(body.q.shape)
    body.v[body.fixed] = 0.0
    dt = 0.01
    scene, stepper = _prepared(body, dt)
    _, expected = _solve_step(body, scene, dt)
    solve, _, _ = _gauss_seidel(stepper, dt)
    _start(stepper, body.v)
    sweeps, solved = solve.solve(SWEEP_TOLERANCE)
    assert sweeps < solve.max_sweeps
    np.testing.assert_allclose(solved.numpy(), expected, atol=VELOCITY_TOL, rtol=0)


def test_gauss_seidel_spectrum_encloses_the_dense_eigenvalues_and_sets_the_measured_rate():
    """M^-1 A of symmetric block Gauss-Seidel (M = (D + L) D^-1 (D + U) in colour order), dense
    in NumPy: the Lanczos bounds enclose its spectrum, and the sweeps' measured error decay per
    decade is the Chebyshev rate of those bounds, below node-block Jacobi's measured one."""
    body = _stiff_block()
    dt = 0.01
    scene, stepper = _prepared(body, dt)
    system, expected = _solve_step(body, scene, dt)
    solve, colours, bounds = _gauss_seidel(stepper, dt, max_sweeps=60)
    a, free = free_matrix(stepper.model, stepper.state)
    index = np.cumsum(free) - 1
    order = index[colours.order[free[colours.order]]]
    dofs = (3 * order[:, None] + np.arange(3)).ravel()
    dense = a.toarray()[np.ix_(dofs, dofs)]
    node = np.arange(len(dense)) // 3
    d = np.where(node[:, None] == node[None, :], dense, 0.0)
    lower = d + np.tril(dense - d)
    m = lower @ np.linalg.solve(d, lower.T)
    eig = np.sort(np.linalg.eigvals(np.linalg.solve(m, dense)).real)
    assert bounds[0] <= eig[0] <= bounds[0] / SPECTRUM_MARGIN[0] * 1.001 and eig[-1] <= bounds[1]
    rho_gs = np.abs(1.0 - eig).max()  # spectral radius of the plain iteration matrix I - M^-1 A
    assert rho_gs < 1.0

    def measured(solve):
        errors = []
        for k in (20, 60):
            solve.max_sweeps = k
            _start(stepper, np.zeros_like(expected))
            _, solved = solve.solve(0.0)
            errors.append(np.abs(solved.numpy() - expected).max())
        return 40 / np.log10(errors[0] / errors[1])

    gs = measured(solve)
    jacobi = measured(NodeSolve(stepper.model, stepper.state, dt, spectrum(stepper.model, stepper.state),
                                max_sweeps=60))
    # The Chebyshev rate on [lo, hi] ~ (1 - sqrt(kappa^-1))...: within 30 % of the measured
    # decay (the error's polynomial prefactor and the 0.8 margin on lo).
    expected_gs = sweeps_per_decade((eig[0] * SPECTRUM_MARGIN[0], eig[-1] * SPECTRUM_MARGIN[1]))
    assert gs == pytest.approx(expected_gs, rel=0.3)
    assert gs < 0.6 * jacobi


@pytest.mark.parametrize("gpu_forms", [False, True], ids=["one-thread contacts", "thread per contact"])
def test_a_gauss_seidel_contact_step_solves_the_mlcp_of_eq_5_5(monkeypatch, gpu_forms):
    """A cube dropped on a plane, stepped with Gauss-Seidel sweeps (forced), held to eq. 5.5 by
    the checker of tests/sim/test_node_arrays.py; the contact step in the middle of each sweep
    walked by one thread or a thread per contact (the GPU forms: Jacobi passes on split masses)."""
    chosen = []

    def gauss_seidel(*args, **kwargs):
        monkeypatch.setattr(_node_sweeps, "sweep_costs", lambda *a: (1e9, 1.0))
        choice = _node_sweeps.choose_sweeps(*args, **kwargs)
        chosen.append(choice.kind)
        return choice

    monkeypatch.setattr(_node_step, "choose_sweeps", gauss_seidel)
    body = _cube()
    scene = _scene(body)
    scene._gpu_forms = gpu_forms or scene._gpu_forms  # (pytest --gpu-forms sets it for every scene)
    assert check_mlcp_steps(body, scene, 1.0 / 60.0, 40, friction=0.5) >= 10
    assert chosen == ["gauss-seidel"]
    assert scene._stepper._recorded[5].parallel == scene._gpu_forms


def test_a_soft_cube_keeps_jacobi_sweeps_and_contacts_favour_fewer_sweeps(monkeypatch):
    # The rule (choose_sweeps): each kind's work per decade counts its sweeps' node updates,
    # launches and contact passes; on a soft cube Jacobi's 3-4 sweeps per decade leave
    # Gauss-Seidel nothing to gain at 2-3x the node work of a sweep. Contacts cost the same per
    # sweep of either kind, so many of them make the kind with fewer sweeps per decade cheaper.
    body = _cube()
    _, stepper = _prepared(body, 1.0 / 60.0, plane=True)
    a, free = free_matrix(stepper.model, stepper.state)
    m = stepper.model
    # By default a cube this soft does not even estimate Gauss-Seidel (GAUSS_SEIDEL_FROM); the
    # cost model is checked with the estimate forced.
    default = _node_sweeps.choose_sweeps(m.row_start.numpy(), m.block_col.numpy(), a, free,
                                         spectrum(m, stepper.state), 25.0, 0, 2, SPECTRUM_MARGIN)
    assert default.kind == "jacobi" and set(default.work) == {"jacobi"}
    monkeypatch.setattr(_node_sweeps, "GAUSS_SEIDEL_FROM", 0.0)
    choice = _node_sweeps.choose_sweeps(m.row_start.numpy(), m.block_col.numpy(), a, free,
                                        spectrum(m, stepper.state), 25.0, 0, 2, SPECTRUM_MARGIN)
    assert choice.kind == "jacobi" and choice.work["jacobi"] < choice.work["gauss-seidel"]
    crowded = _node_sweeps.choose_sweeps(m.row_start.numpy(), m.block_col.numpy(), a, free,
                                         spectrum(m, stepper.state), 25.0, 10 ** 6, 2, SPECTRUM_MARGIN)
    assert crowded.work["gauss-seidel"] / crowded.work["jacobi"] < choice.work["gauss-seidel"] / choice.work["jacobi"]
    assert crowded.kind == "gauss-seidel"  # its fewer sweeps (the spectrum test) now win


def _cube_choice_args(monkeypatch):
    """choose_sweeps' first five arguments for the soft cube on a plane (pattern, A, free nodes,
    Jacobi's bounds), Gauss-Seidel estimated whatever Jacobi's work (GAUSS_SEIDEL_FROM 0)."""
    _, stepper = _prepared(_cube(), 1.0 / 60.0, plane=True)
    m = stepper.model
    a, free = free_matrix(m, stepper.state)
    monkeypatch.setattr(_node_sweeps, "GAUSS_SEIDEL_FROM", 0.0)
    return m.row_start.numpy(), m.block_col.numpy(), a, free, spectrum(m, stepper.state)


def test_gauss_seidel_within_its_limit_is_taken_where_jacobi_is_over_its_own(monkeypatch):
    # Where Jacobi is over its limit the alternative to Gauss-Seidel is the per-object LU, so
    # Gauss-Seidel within MAX_GAUSS_SEIDEL_WORK_PER_DECADE is taken even at more work than
    # Jacobi's (the shoulder, both at ~39.5, was declined by the strict comparison).
    args = _cube_choice_args(monkeypatch)
    free_choice = _node_sweeps.choose_sweeps(*args, 25.0, 0, 2, SPECTRUM_MARGIN)
    jacobi, gauss_seidel = free_choice.work["jacobi"], free_choice.work["gauss-seidel"]
    assert jacobi < gauss_seidel <= _node_sweeps.MAX_GAUSS_SEIDEL_WORK_PER_DECADE
    limited = _node_sweeps.choose_sweeps(*args, 0.5 * jacobi, 0, 2, SPECTRUM_MARGIN)
    assert limited.kind == "gauss-seidel"


@pytest.mark.parametrize("colour_chunk, form", [(node_gauss_seidel.COLOUR_CHUNK, "launches"), (4, "launches"),
                                                (node_gauss_seidel.COLOUR_CHUNK, "block"),
                                                (node_gauss_seidel.COLOUR_CHUNK, "block lanes")])
def test_one_sweep_is_numpy_symmetric_block_gauss_seidel_in_colour_order(monkeypatch, colour_chunk, form):
    """One sweep's node update (kernels of softvr.contact._node_gs_kernels, the rows read from
    their colour-ordered copy) against the sweep written out in NumPy on A, b of eq. 5.2 as
    the per-object path assembles them (SciPy): colours forward, x_i = A_ii^-1 (b_i -
    sum_{j != i} A_ij x_j); the contact nodes (a random fifth, marked by hand) damped Jacobi,
    (1 - omega) v_i + omega A_ii^-1 (b_i - sum_{j != i} A_ij x_j), from the swept x; colours
    backward. No contact projects anything. Tolerance: each update is a sum of at most 27
    block products in f64, so it carries a rounding of ~81 eps times the sum of the magnitudes
    of its terms (Higham, dot products: gamma_n); 4x that, over both halves, per node. Both
    ways of launching the colours: one launch walking them all (no colour split over the
    CPU cores) and one a colour, split (``COLOUR_CHUNK`` 4); and the GPU's form
    (``parallel``), one block before and one after the contact step, with one lane or with
    its lanes as cooperative fibers (``wp.config.enable_cpu_blocks``: they interleave at the
    block's barriers, so a missing one shows)."""
    monkeypatch.setattr(node_gauss_seidel, "COLOUR_CHUNK", colour_chunk)
    if form == "block lanes":
        monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    body = _stiff_block(cells=3)
    rng = np.random.default_rng(2)
    body.v = 0.05 * rng.standard_normal(body.q.shape)
    body.v[body.fixed] = 0.0
    dt, omega = 0.01, 0.7
    scene, stepper = _prepared(body, dt)
    m, n = stepper.model, len(body.q)
    colours = colour_nodes(m.row_start.numpy(), m.block_col.numpy())
    assert colours.count >= 4
    sweep = GaussSeidelSweep(m, stepper.state, colours, omega, parallel=form != "launches")
    sweep.prepare()
    contact = rng.random(n) < 0.2
    contact[body.fixed] = False
    sweep.set_contact_nodes(contact)
    v = wp.array(body.v, dtype=wp.vec3d, device=m.device)
    sweep.record(v, lambda: None)()

    system = body.step_system(dt, scene.gravity)
    a = system.matrix.toarray().reshape(n, 3, n, 3).transpose(0, 2, 1, 3)
    b = system.rhs.reshape(n, 3)
    fixed = system.prescribed.reshape(n, 3).all(axis=1)
    x, size = body.v.copy(), np.zeros(n)

    def update(i):
        others = np.arange(n) != i
        terms = np.einsum("jab,jb->ja", a[i, others], x[others])
        size[i] += np.abs(np.linalg.inv(a[i, i])).max() * (np.abs(b[i]).max() + np.abs(terms).sum(axis=0).max())
        return np.linalg.solve(a[i, i], b[i] - terms.sum(axis=0))

    def half(order):
        for i in order:
            if not contact[i]:
                x[i] = system.value.reshape(n, 3)[i] if fixed[i] else update(i)

    half(colours.order)
    x[contact] = [(1.0 - omega) * body.v[i] + omega * update(i) for i in np.flatnonzero(contact)]
    half(colours.order[::-1])
    assert contact.sum() > 5 and not np.allclose(x, body.v)
    tolerance = 4 * 81 * np.finfo(float).eps * size
    np.testing.assert_array_less(np.abs(stepper.state.v_hat.numpy() - x).max(axis=1), tolerance + 1e-300)


def test_sleeping_contacts_wake_when_the_sweeps_close_their_gap_and_meet_eq_5_5(monkeypatch):
    """A cube squeezed to 80 % of its height and released 2 mm over a plane, without gravity:
    the step's first guess (the explicit step: no elastic force) leaves it at rest, so no
    contact pushes or closes its gap and all sleep (their nodes take the Gauss-Seidel update);
    the released cube's bottom moves down by far more than 2 mm in the step, so the PGS must
    push: the contacts are woken, and every step holds to eq. 5.5 (checker of
    tests/sim/test_node_arrays.py: normal velocity >= -gap / dt, complementarity, the friction
    disc, A v - b - J^T lambda within the sweeps' tolerance)."""
    asleep, wakes = [], []
    prepare, solve = GaussSeidelSweep.prepare, NodeSolve.solve

    def prepared(self):
        prepare(self)
        asleep.append(int(self.asleep.numpy().sum()))

    def solved(self, tolerance, check_every=2, then=None, batch=None):
        out = solve(self, tolerance, check_every, then, batch)
        wakes.append(self.wakes)
        return out

    def gauss_seidel(*args, **kwargs):
        monkeypatch.setattr(_node_sweeps, "sweep_costs", lambda *a: (1e9, 1.0))
        return _node_sweeps.choose_sweeps(*args, **kwargs)

    monkeypatch.setattr(_node_step, "choose_sweeps", gauss_seidel)
    monkeypatch.setattr(GaussSeidelSweep, "prepare", prepared)
    monkeypatch.setattr(NodeSolve, "solve", solved)
    body = _cube(lift=0.0)
    bottom = body.q[:, 2].min()
    body.q = body.q * [1.0, 1.0, 0.8] + [0.0, 0.0, 0.002 - 0.8 * bottom]
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(body.q))[:, None],
                                                         np.ones((len(body.q), 1))))
    scene.add_plane(Plane(friction=0.5))
    assert check_mlcp_steps(body, scene, 1.0 / 60.0, 3, friction=0.5) == 3
    assert asleep[0] >= 25 and wakes[0] >= 1  # the 5x5 bottom nodes slept, then woke
    assert body.q[:, 2].min() > -1e-6


def test_a_light_held_box_pressed_on_a_plane_by_25_contacts_solves_scipys_mlcp_of_eq_5_5_in_one_check(monkeypatch):
    """A 2.4 g box on two springs to a fixed anchor (a haptic tool on its handle) moving down
    onto a frictionless plane, 5x5 contact points on its bottom face (up to 15 pushing: far
    more rows than its 6 dofs), Gauss-Seidel sweeps forced. Truth: eq. 5.5 with the box's A
    and b written out (tests/sim/test_node_rigid_couplings.py's _box_system) and one row
    n . (v + omega x r) >= -gap / dt per point, solved as its primal QP by SciPy's SLSQP
    (strictly convex: v is unique though the impulses are not). The box's update is exact
    (undamped: its 6x6 block of D_A is all of its A) and its contacts get TOOL_PASSES more PGS
    passes a sweep, so every step stops at its first check (2 sweeps) on SciPy's velocity
    within the sweeps' VELOCITY_TOL (omega: over the largest lever, 0.035 m). Damped by omega
    (before), the first step stopped at 2 sweeps 0.015 rad/s off (the stop reads only the
    contacts' residual on an exact body); with no extra passes the second took 4 sweeps."""
    def gauss_seidel(*args, **kwargs):
        monkeypatch.setattr(_node_sweeps, "sweep_costs", lambda *a: (1e9, 1.0))
        return _node_sweeps.choose_sweeps(*args, **kwargs)

    monkeypatch.setattr(_node_step, "choose_sweeps", gauss_seidel)
    block = _block((0.3, 0.0, 0.0))  # the arrays need an FEM body: a clamped one, apart
    block.fixed[:] = True
    half = 0.02
    box = RigidBody.box((2 * half,) * 3, 300.0, position=(0.0, 0.0, half + 0.0005), name="box",
                        orientation=Rotation.from_rotvec([0.02, -0.03, 0.01]).as_quat(scalar_first=True),
                        velocity=(0.01, -0.02, -0.08), angular_velocity=(0.5, -0.3, 0.2))
    anchor = FixedBody(position=(0.0, 0.0, 0.0), name="anchor")
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.0, pgs_iterations=500)
    scene.add_body(block)
    grid = np.linspace(-half, half, 5)
    points = np.array([[x, y, -half] for x in grid for y in grid])
    scene.add_plane(Plane(friction=0.0))
    scene.add_body(box, collision_points=RigidPoints(box, points))
    scene.add_body(anchor)
    ties = [Coupling(RigidPoints(box, [[0.03, 0.0, 0.0], [0.0, -0.025, 0.01]]),
                     RigidPoints(anchor, [[0.05, 0.01, 0.03], [-0.01, -0.04, 0.0]]), 200.0, damping=0.5)]
    scene.add_coupling(ties[0])
    dt = 0.01
    normal = np.array([0.0, 0.0, 1.0])
    pressed = []
    for _ in range(3):
        a, b = _box_system(box, ties, dt)
        levers = points @ box.rotation.T
        jac = np.hstack([np.tile(normal, (len(points), 1)), np.cross(levers, normal)])
        gap = box.position[2] + levers[:, 2]
        near = gap < 0.002 + 0.1 * dt  # within the margin plus the motion over the step
        rows, floor = jac[near], -gap[near] / dt
        truth = so.minimize(lambda v: 0.5 * v @ a @ v - b @ v, np.linalg.solve(a, b), jac=lambda v: a @ v - b,
                            constraints=[{"type": "ineq", "fun": lambda v: rows @ v - floor, "jac": lambda v: rows}],
                            method="SLSQP", options={"ftol": 1e-15, "maxiter": 1000}).x
        pressed.append(int((rows @ np.linalg.solve(a, b) < floor).sum()))  # rows the contacts must push
        solution = scene.step(dt)
        assert scene._stepper is not None and scene._stepper._recorded[5].colours is not None
        assert solution.iterations <= 2
        np.testing.assert_allclose(box.v[:3], truth[:3], atol=VELOCITY_TOL, rtol=0)
        np.testing.assert_allclose(box.v[3:], truth[3:], atol=VELOCITY_TOL / 0.035, rtol=0)
    assert pressed[0] >= 10 and pressed[1] > 0


@pytest.mark.parametrize("share, kind", [(0.64, "coarse"), (0.77, "gauss-seidel"), (1.0, "gauss-seidel")])
def test_the_coarse_correction_is_taken_over_gauss_seidel_only_at_the_shares_where_it_was_measured_to_pay(
        monkeypatch, share, kind):
    # Truth: the bundled scenes' measured outcomes at their coarse / Gauss-Seidel work shares
    # (COARSE_OVER_GAUSS_SEIDEL's comment), one rule with or without a held tool: the head CT of
    # palpation.toml (0.64) steps faster on the coarse sweeps; the arthroscopy (0.77 when it was
    # measured: every step at the 100-sweep cap on them, Gauss-Seidel 14 / 77 sweeps) and
    # shoulder.toml (1.0: at the cap, changes ~1e-2 m/s) do not. A coarse estimate stubbed at
    # each share over the soft cube's Gauss-Seidel estimate, both over Jacobi's limit.
    args = _cube_choice_args(monkeypatch)
    bounds = args[-1]
    plain = _node_sweeps.choose_sweeps(*args, 25.0, 0, 2, SPECTRUM_MARGIN)
    gauss_seidel = plain.work["gauss-seidel"]
    limit = 0.5 * min(plain.work["jacobi"], share * gauss_seidel)  # Jacobi over it, the coarse estimate too

    def coarse_choice(a, free, coarse, jacobi_cost, margin, work):
        work["coarse"] = share * gauss_seidel
        return _node_sweeps.SweepChoice("jacobi", bounds, None, 1.0, work, coarse=np.array([[0, 1]]))

    monkeypatch.setattr(_node_sweeps, "_coarse_choice", coarse_choice)
    choice = _node_sweeps.choose_sweeps(*args, limit, 0, 2, SPECTRUM_MARGIN, (np.array([[0, 1]]),))
    assert ("coarse" if choice.coarse is not None else choice.kind) == kind


def _dense_system(model, state, v):
    """``(A, b, free)`` of eq. 5.2 written out densely from the node arrays' rows (every node's
    3x3 blocks, a spring-held rigid body's included), the fixed nodes' columns moved to ``b``
    at their velocities in ``v`` [n, 3]; ``free`` [3 n] bool the dofs solved for."""
    n = model.node_count
    rows, cols, blocks = model.block_row.numpy(), model.block_col.numpy(), state.blocks.numpy()
    a = np.zeros((3 * n, 3 * n))
    for r, c, block in zip(rows, cols, blocks):
        a[3 * r:3 * r + 3, 3 * c:3 * c + 3] += block
    free = np.repeat(model.fixed.numpy() == 0, 3)
    b = state.b.numpy().ravel() - a[:, ~free] @ v.ravel()[~free]
    return a[free][:, free], b[free], free


def _contact_rows(contacts, n):
    """Each contact's rows ``frame J`` [c, 3, 3 n] of its relative velocity (thesis eq. 5.5:
    stencil weights on its nodes, ``-[lever]x`` on a rigid side's angular node)."""
    count = int(contacts.count.numpy()[0])
    out = np.zeros((count, 3, 3 * n))
    stencil, weights = contacts.stencil_nodes.numpy(), contacts.stencil_weights.numpy()
    rigid, levers, frames = contacts.rigid_node.numpy(), contacts.rigid_lever.numpy(), contacts.frame.numpy()
    for c in range(count):
        j = np.zeros((3, 3 * n))
        for k in range(contacts.stencil_count.numpy()[c]):
            j[:, 3 * stencil[c, k]:3 * stencil[c, k] + 3] += weights[c, k] * np.eye(3)
        for s in range(rigid.shape[1]):
            if rigid[c, s] >= 0:
                lever = levers[c, s]
                j[:, 3 * rigid[c, s]:3 * rigid[c, s] + 3] -= np.array([[0.0, -lever[2], lever[1]],
                                                                      [lever[2], 0.0, -lever[0]],
                                                                      [-lever[1], lever[0], 0.0]])
        out[c] = frames[c] @ j
    return out


MU = 1.0


@pytest.mark.parametrize("gpu_forms", [False, True, "lanes"],
                         ids=["one-thread contacts", "thread per contact", "thread per contact, lanes"])
def test_a_light_held_box_pressed_into_a_soft_block_with_friction_meets_numpys_kkt_solve_of_eq_5_5(monkeypatch,
                                                                                                   gpu_forms):
    """A 9.6 g box on a spring to a fixed anchor (a haptic tool on its handle) pressed into a soft
    FEM block (1e5 Pa, bottom clamped) with friction 1, Gauss-Seidel sweeps forced: the
    shoulder's pressing steps in small (a light exact tool whose contacts stick and slide on
    damped tissue contact nodes). Truth, each
    pressing step: eq. 5.5 on the active set the solve leaves (a pushing contact sticks, rows
    ``frame J v = (-gap / dt, 0, 0)``, or, with its friction on the disc's rim, slides: its
    normal row and ``lambda_t = mu lambda_n d``, d its friction's direction), A and b written
    out from the step's rows and the contacts' J from their stencils, the KKT system solved by
    NumPy. The truth must itself meet eq. 5.5 (pushes, friction in the disc, a slide's slip
    opposite d, the other contacts not closing past their gaps), so it is the LCP's solution
    on that set, and the sweeps' velocities must be within VELOCITY_TOL of it (the box's spin
    over its 0.03 m half-diagonal). With the contact step walked by one thread or a thread per
    contact (the GPU forms, whose extra passes over the tool's contacts are Jacobi ones too;
    their sweeps two blocks around the contact step's, "lanes": the blocks' lanes cooperative
    fibers, interleaving at every barrier)."""
    if gpu_forms == "lanes":
        monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    def gauss_seidel(*args, **kwargs):
        monkeypatch.setattr(_node_sweeps, "sweep_costs", lambda *a: (1e9, 1.0))
        return _node_sweeps.choose_sweeps(*args, **kwargs)

    monkeypatch.setattr(_node_step, "choose_sweeps", gauss_seidel)
    solved = {}
    solve = NodeSolve.solve

    def keep(self, tolerance, check_every=2, then=None, batch=None):
        k, buffer = solve(self, tolerance, check_every, then, batch)
        solved["v"], solved["solve"] = buffer.numpy().copy(), self
        return k, buffer

    monkeypatch.setattr(NodeSolve, "solve", keep)
    scene = Scene(gravity=(0.0, 0.0, -G), friction=MU, pgs_iterations=500)
    scene._gpu_forms = bool(gpu_forms)
    block = _surface_block(3, 0.1, (0.0, 0.0, -0.05), Material(1e5, 0.3, 1000.0, alpha=0.0, beta=1e-3),
                           fixed=lambda x: x[:, 2] < -0.099)
    _add_with_surface(scene, block)
    half = np.array([0.02, 0.02, 0.01])
    box = _rigid_box(scene, half, 300.0, (0.0, 0.0, half[2] + 0.0005), velocity=(0.002, -0.001, -0.1))
    anchor = FixedBody(position=(0.0, 0.0, 2 * half[2] - 0.0025), name="anchor")  # the spring pushes 0.6 N
    scene.add_body(anchor)
    scene.add_coupling(Coupling(RigidPoints(box, [[0.0, 0.0, half[2]]]), RigidPoints(anchor, [[0.0, 0.0, 0.0]]),
                                200.0, damping=0.5))
    dt = 0.01
    checked = 0
    for _ in range(6):
        scene.step(dt)
        stepper = scene._stepper
        model, state, v = stepper.model, stepper.state, solved["v"]
        lam = state.contacts.impulse.numpy()[:int(state.contacts.count.numpy()[0])]
        pushing = lam[:, 0] > 0.0
        if not pushing.any():
            continue
        assert solved["solve"].colours is not None and solved["solve"].parallel == scene._gpu_forms
        a, b, free = _dense_system(model, state, v)
        all_rows = _contact_rows(state.contacts, model.node_count)
        rows, moving = all_rows[:, :, free], all_rows[:, :, ~free] @ v.ravel()[~free]  # the fixed nodes' share
        gap = state.contacts.gap.numpy()[:len(lam)]
        # The solve's active set: a pushing contact slides where its friction is on the disc's rim.
        rim = np.hypot(lam[:, 1], lam[:, 2]) >= (1.0 - 1e-6) * MU * lam[:, 0]
        slide = np.where(rim[:, None], lam[:, 1:] / np.maximum(np.hypot(lam[:, 1], lam[:, 2]), 1e-300)[:, None], 0.0)
        active = np.flatnonzero(pushing)
        size, m = a.shape[0], len(active)
        kkt = np.zeros((size + 3 * m, size + 3 * m))
        rhs = np.zeros(size + 3 * m)
        kkt[:size, :size], rhs[:size] = a, b
        for k, c in enumerate(active):
            kkt[:size, size + 3 * k:size + 3 * k + 3] = -rows[c].T
            r = size + 3 * k
            kkt[r, :size], rhs[r] = rows[c, 0], -gap[c] / dt - moving[c, 0]
            for t_ in (1, 2):  # sticking: no slip; sliding: friction mu lambda_n along the slip's opposite
                if rim[c]:
                    kkt[r + t_, size + 3 * k + t_], kkt[r + t_, size + 3 * k] = 1.0, -MU * slide[c, t_ - 1]
                else:
                    kkt[r + t_, :size], rhs[r + t_] = rows[c, t_], -moving[c, t_]
        x = np.linalg.solve(kkt, rhs)
        truth, impulses = x[:size], x[size:].reshape(-1, 3)
        rel = np.einsum("cij,j->ci", rows, truth) + moving
        # The truth meets eq. 5.5: pushing contacts at their targets, friction in its disc, a
        # sliding one's slip opposite its friction, the rest not closing past their gaps.
        assert (impulses[:, 0] > 0).all()
        assert (np.hypot(impulses[:, 1], impulses[:, 2]) <= MU * impulses[:, 0] * (1 + 1e-9)).all()
        slip = rel[active][rim[active], 1:]
        along = -np.einsum("ci,ci->c", slip, slide[active][rim[active]])
        assert (along >= -VELOCITY_TOL).all()
        np.testing.assert_allclose(slip, -along[:, None] * slide[active][rim[active]], atol=VELOCITY_TOL, rtol=0)
        assert (rel[~pushing, 0] >= -gap[~pushing] / dt - VELOCITY_TOL).all()
        mine = v.ravel()[free]
        angular = np.zeros(model.node_count, bool)  # the box's spin node: its contacts' rigid side
        angular[state.contacts.rigid_node.numpy()[:len(lam)][state.contacts.rigid_node.numpy()[:len(lam)] >= 0]] = True
        spin = np.repeat(angular, 3)[free]
        assert spin.sum() == 3
        np.testing.assert_allclose(mine[~spin], truth[~spin], atol=VELOCITY_TOL, rtol=0)
        np.testing.assert_allclose(mine[spin], truth[spin], atol=VELOCITY_TOL / 0.03, rtol=0)
        checked += 1
    assert checked >= 3


def test_the_islands_contact_response_in_the_gpu_form_equals_the_one_thread_walks():
    """The rigid islands' step 2 of a Gauss-Seidel sweep (each island in contact solved whole
    for the contacts' last impulses, _node_gs_kernels.island_contact) with a thread per island
    node, contact and island (the GPU form) against the one-thread walk over the islands and
    contacts (the obviously correct reference), on the shoulder's fingers pressed into tissue
    with random impulses on all its contacts: the same velocities, bit for bit (on one CPU thread
    the atomic sums add in contact order, as the walk does)."""
    with load_scene(bundled("shoulder.toml"), frames=1, width=64, height=48, haptics=False) as example:
        for _ in range(30):
            example.step()
        stepper = example.scene._stepper
        gs = stepper._recorded[5]._gauss_seidel
        assert gs is not None and gs._islands is not None
        c = stepper.state.contacts
        n = int(c.count.numpy()[0])
        impulse = c.impulse.numpy()
        impulse[:n] = np.random.default_rng(4).standard_normal((n, 3))
        c.impulse.assign(impulse)
        islands = gs._islands[1].numpy()
        contact = gs.contact_node.numpy()
        contact[islands] = 1  # every island in contact
        gs.contact_node.assign(contact)
        w = stepper.state.sweep_buffers[0]
        before = stepper.state.v_hat.numpy().copy()
        results = []
        for parallel in (False, True):
            stepper.state.v_hat.assign(before)
            for replay in gs.island_contact(w, parallel):
                replay()
            results.append(stepper.state.v_hat.numpy().copy())
        assert not np.array_equal(results[0][islands], before[islands])  # the islands moved
        np.testing.assert_array_equal(results[1], results[0])
