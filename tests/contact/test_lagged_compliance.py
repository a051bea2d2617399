"""A contact step that reuses an earlier factorization still solves this step's MLCP exactly.

With a kept factorization the PGS sees an earlier step's compliance B~ = J A~^-1 J^T, and the
outer loop of thesis eq. 5.6 moves (B - B~) lambda to the right-hand side until it stops
changing. The truth the test holds the step to is the MLCP of eq. 5.5 itself, with this step's
``A`` and ``b`` solved by SciPy's sparse direct solver:

    A v = b + J^T lambda,     lambda_n >= 0,     n . v_contact >= -gap / dt,
    lambda_n (n . v_contact + gap / dt) = 0   (per contact, to the PGS tolerance).

Tolerances: the PGS stops when no row changes its velocity by more than 1e-5 m/s, so a normal
constraint may be violated by a few times that; v is v_free + A^-1 J^T lambda from two CG
solves, each stopping at a residual of 1e-8 of its right-hand side, so
``|A v - b - J^T lambda| <= 1e-8 (|b| + |J^T lambda|)`` (checked with a factor 10 for round-off);
the velocities themselves may then differ from a direct solve by the condition number of A
times that (up to ~1e3 here: 1e-5 relative).
"""

import numpy as np
import scipy.sparse.linalg as spla

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import EmbeddedPoints, FemBody, Material
from softvr.volume import Volume, grid_tet_mesh

PGS_TOLERANCE = 1e-5  # [m/s], solve_contacts' default
CG_TOLERANCE = 1e-8  # FemBody.cg_tolerance: |r| <= 1e-8 |rhs| for each of the two solves


def _cube_on_plane():
    cells, size = 4, 0.4
    spacing = np.full(3, size / cells)
    corner = np.array([-size / 2, -size / 2, 0.002])
    nodes, tets = grid_tet_mesh(Volume(np.zeros((cells,) * 3, np.uint8), spacing=spacing,
                                       origin=spacing / 2 + corner), cells)
    body = FemBody(nodes, tets, Material(2.5e5, 0.25, 1000.0, alpha=0.0, beta=1e-3), name="cube")
    # The per-object path: the kept factorization under test is its own (the node arrays have none).
    scene = Scene(gravity=(0.0, 0.0, -9.81), node_arrays=False)
    scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(nodes))[:, None],
                                                         np.ones((len(nodes), 1))))
    scene.add_plane(Plane(friction=0.5))
    return scene, body


def test_kept_factorization_solves_the_exact_mlcp():
    scene, body = _cube_on_plane()
    dt = 1.0 / 60.0
    lagged_steps = 0
    for step in range(40):
        system = body.step_system(dt, scene.gravity)  # this step's A and b (eq. 5.2), before it runs
        solution = scene.step(dt)
        if not solution.contacts:
            continue
        lagged_steps += not body.compliance_is_exact
        # J^T lambda as node forces [N s]: every contact is one node (a collision point per node).
        impulse = np.zeros((len(body.q), 3))
        for contacts, lam, frames in zip(solution.contacts, solution.impulses, solution.frames):
            world = np.einsum("ci,cij->cj", lam, frames)
            np.add.at(impulse, contacts.a.blocks[:, 0], np.einsum("cij,ci->cj", contacts.a.jac[:, 0], world))
            v_contact = body.v[contacts.a.blocks[:, 0]]
            approach = np.einsum("ci,ci->c", v_contact, contacts.normal) + contacts.gap / dt
            assert lam[:, 0].min() >= 0.0, f"step {step}: a pulling normal impulse without adhesion"
            assert approach.min() >= -5 * PGS_TOLERANCE, f"step {step}: normal constraint violated by {-approach.min()}"
            assert np.abs(lam[:, 0] * approach).max() <= 5 * PGS_TOLERANCE * lam[:, 0].max(), f"step {step}"
        free = ~system.prescribed
        a = system.matrix.tocsr()[free][:, free]
        rhs, jt_lam = system.rhs[free], impulse.ravel()[free]
        residual = np.linalg.norm(a @ body.v.ravel()[free] - rhs - jt_lam)
        bound = 10 * CG_TOLERANCE * (np.linalg.norm(rhs) + np.linalg.norm(jt_lam))
        assert residual <= bound, f"step {step}: |A v - b - J^T lambda| = {residual:.2e} > {bound:.2e}"
        # The same step by SciPy's direct solver: the velocities agree to CG's accuracy.
        v_exact = spla.spsolve(a.tocsc(), rhs + jt_lam)
        error = np.abs(body.v.ravel()[free] - v_exact).max()
        assert error < 1e-5 * np.abs(v_exact).max() + PGS_TOLERANCE, f"step {step}: velocities off by {error:.2e} m/s"
    assert lagged_steps >= 10, "the kept factorization was never used: the test checks nothing new"
