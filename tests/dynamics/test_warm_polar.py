"""The warm-started polar rotation of the node elements (``_fem_kernels.warm_polar_rotation``)
against SciPy's polar decomposition (``scipy.linalg.polar``, via the SVD).

The rotation R_e of the co-rotated FEM of thesis eq. 5.2 (K = sum_e R_e K_e R_e^T) is the polar
factor of F = Ds Dm^-1. Started from a rotation within theta of it, Newton's method on R stops
after a correction w with |w| <= 1e-8: the error left is O(|w|^2) = 1e-16. Both it and the
SVD-based reference then carry round-off of forming F's products and the factorization,
~c u kappa(F) (u = 1.1e-16, kappa(F) = sigma_max / sigma_min): c = 50 covers the few dozen
operations of either (measured: 5e-15 at kappa ~2, both ways, and the cold iteration the same).
"""

import numpy as np
import scipy.linalg
import warp as wp
from scipy.spatial.transform import Rotation

from softvr import Scene
from softvr.dynamics import EmbeddedPoints, FemBody, Material
from softvr.dynamics._fem_kernels import warm_polar_rotation
from softvr.sim._node_step import NodeStepper
from softvr.volume import Volume, grid_tet_mesh

U = np.finfo(float).eps / 2


@wp.kernel
def _warm(f: wp.array(dtype=wp.mat33d), r0: wp.array(dtype=wp.mat33d), out: wp.array(dtype=wp.mat33d)):
    i = wp.tid()
    out[i] = warm_polar_rotation(f[i], r0[i])


def _bound(f: np.ndarray) -> np.ndarray:
    s = np.linalg.svd(f, compute_uv=False)
    return 50 * U * s[:, 0] / s[:, -1]


def test_rotations_started_from_last_steps_are_scipys_polar_factors():
    """Deformation gradients of strains up to 0.3 (and a few inverted: the SVD fallback),
    started from the true R turned by 0 .. 1e-2 rad (the warm path), 0.5 rad and from zeros
    (the cold fallbacks): R within 50 u kappa(F) of SciPy's polar factor, and orthogonal to
    50 u (the Newton-Schulz step after the corrections)."""
    wp.init()
    rng = np.random.default_rng(11)
    n = 400
    rot = Rotation.random(n, random_state=rng).as_matrix()
    stretch = np.eye(3) + 0.3 * rng.uniform(-1, 1, (n, 1, 1)) * rng.standard_normal((n, 3, 3))
    f = rot @ (0.5 * (stretch + stretch.transpose(0, 2, 1)))
    f[:5] = f[:5] @ np.diag([1.0, 1.0, -1.0])  # inverted tets: R = U V^T of the SVD
    truth = np.stack([scipy.linalg.polar(a)[0] for a in f])
    proper = np.linalg.det(f) > 0
    axis = rng.standard_normal((n, 3))
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    for turn in (0.0, 1e-12, 1e-9, 1e-6, 1e-4, 1e-2, 0.5, None):
        r0 = np.zeros_like(f) if turn is None else truth @ Rotation.from_rotvec(turn * axis).as_matrix()
        out = wp.empty(n, dtype=wp.mat33d, device="cpu")
        wp.launch(_warm, n, [wp.array(f, dtype=wp.mat33d, device="cpu"), wp.array(r0, dtype=wp.mat33d, device="cpu"),
                             out], device="cpu")
        r = out.numpy()
        err = np.abs(r - truth).max(axis=(1, 2))
        assert np.all(err[proper] <= _bound(f[proper])), (turn, err[proper].max())
        assert np.abs(r.transpose(0, 2, 1) @ r - np.eye(3)).max() <= 50 * U, turn
        assert np.allclose(np.linalg.det(r), 1.0)


def test_a_steps_element_rotations_from_the_last_ones_are_scipys_polar_factors():
    """The node stepper's elements replayed at a deformed, turned cube (cold: the rotations
    start at zero), then at it turned on by 1e-3 rad and strained by 1e-4 more (warm from the
    first replay's R_e): every R_e within 50 u kappa(F) of SciPy's polar factor of its F."""
    spacing = np.full(3, 0.1)
    nodes, tets = grid_tet_mesh(Volume(np.zeros((2, 2, 2), np.uint8), spacing=spacing, origin=spacing / 2), 2)
    body = FemBody(nodes, tets, Material(1e5, 0.3, 1000.0))
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(nodes))[:, None], np.ones((len(nodes), 1))))
    stepper = NodeStepper(scene)
    stepper._record(0.008)
    rng = np.random.default_rng(5)
    turn = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
    q = nodes @ turn.T + 0.003 * rng.standard_normal(nodes.shape)
    dm_inv = np.linalg.inv((nodes[tets][:, 1:] - nodes[tets][:, :1]).transpose(0, 2, 1))
    for step in range(2):
        stepper.state.q.numpy()[:] = q  # a view of the CPU array
        stepper._recorded[1]()  # rotations and element forces
        f = (q[tets][:, 1:] - q[tets][:, :1]).transpose(0, 2, 1) @ dm_inv
        truth = np.stack([scipy.linalg.polar(a)[0] for a in f])
        err = np.abs(stepper.state.rotations.numpy() - truth).max(axis=(1, 2))
        assert np.all(err <= _bound(f)), (step, err.max())
        q = q @ Rotation.from_rotvec([1e-3, 0.0, 0.0]).as_matrix().T + 1e-4 * 0.1 * rng.standard_normal(nodes.shape)
