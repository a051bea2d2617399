"""Tissue from voxels against analytic FEM and a brute-force reference.

Truths: every voxel centre of a conforming mesh lies in exactly one tet (a numpy brute-force
barycentric test with the same sub-voxel shift is the reference); a constant volume gives
per tet the table's E, nu, rho exactly, hence the nodal masses (rho V / 4 per tet) and the
stiffness matrix of the homogeneous FEM built directly from a Material, and a total mass of
rho times the mesh volume; an inhomogeneous volume's total mass is the voxel integral of its
density within voxelization (tets on the material interface average their voxels, error
bounded by the interface voxels' share); under equal force a block is indented less where
its voxels are dense, and a two-layer block lies between the homogeneous soft and stiff ones
(static linear FEM, K u = f, Dirichlet bottom).
"""

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from softvr.dynamics import FemBody, Material
from softvr.model import CT_TISSUE, TissueTable, tissue_fem_body, voxel_owners
from softvr.model.tissue import _SHIFT
from softvr.volume import Volume, grid_tet_mesh


def _brute_force_counts(volume, nodes, tets):
    index = volume.world_to_index(nodes)
    centres = np.stack(np.meshgrid(*[np.arange(n) for n in volume.shape], indexing="ij"), -1).reshape(-1, 3) + _SHIFT
    counts = np.zeros(len(centres), int)
    owner = np.full(len(centres), -1)
    for t, tet in enumerate(tets):
        a, b, c, d = index[tet]
        lam = np.linalg.solve(np.c_[b - a, c - a, d - a], (centres - a).T).T
        inside = (lam >= 0).all(axis=1) & (lam.sum(axis=1) <= 1)
        counts[inside] += 1
        owner[inside] = t
    return counts.reshape(volume.shape), owner.reshape(volume.shape)


@pytest.mark.parametrize("jitter", [0.0, 0.3])
def test_every_voxel_has_exactly_one_owner(jitter, device):
    vol = Volume(np.zeros((9, 8, 7), np.float32), spacing=(1.0, 1.5, 2.0), origin=(3.0, -2.0, 1.0))
    nodes, tets = grid_tet_mesh(vol, cells=(3, 2, 2))
    if jitter:  # move interior nodes: tets no longer aligned with the voxel grid
        lo, hi = nodes.min(axis=0), nodes.max(axis=0)
        interior = np.all((nodes > lo + 1e-9) & (nodes < hi - 1e-9), axis=1)
        nodes[interior] += np.random.default_rng(0).uniform(-jitter, jitter, (interior.sum(), 3))
    counts, reference = _brute_force_counts(vol, nodes, tets)
    assert (counts == 1).all()
    np.testing.assert_array_equal(voxel_owners(vol, nodes, tets, device=device), reference)


def test_a_constant_volume_gives_the_homogeneous_fem(device):
    vol = Volume(np.full((12, 12, 12), 40.0, np.float32), spacing=(2.0, 2.0, 2.0))
    nodes, tets = grid_tet_mesh(vol, cells=3)
    body, tissue = tissue_fem_body(vol, nodes, tets, unit=1e-3, device=device)
    e, nu, rho = (float(x) for x in CT_TISSUE(40.0))
    np.testing.assert_allclose(tissue.young, e, rtol=1e-6)
    np.testing.assert_allclose(tissue.poisson, nu, rtol=1e-6)
    np.testing.assert_allclose(tissue.density, rho, rtol=1e-6)
    reference = FemBody(nodes * 1e-3, tets, Material(e, nu, rho))
    np.testing.assert_allclose(body.mass, reference.mass, rtol=1e-6)
    k, k_ref = body.stiffness_matrix(), reference.stiffness_matrix()
    assert abs(k - k_ref).max() <= 1e-6 * abs(k_ref).max()
    assert body.mass.sum() == pytest.approx(rho * (24e-3) ** 3, rel=1e-6)  # the footprint: 12 voxels of 2 mm


def test_total_mass_is_the_voxel_integral_of_density(device):
    """A 30^3 mm block of soft tissue (1050 kg/m^3) holding a bone ball (r 8 mm, 1900):
    interface tets average their voxels; the error is bounded by the interface share."""
    n = 30
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1)
    hu = np.where(np.linalg.norm(ijk - 14.5, axis=-1) < 8.0, 1500.0, 40.0).astype(np.float32)
    vol = Volume(hu, spacing=(1.0, 1.0, 1.0))
    nodes, tets = grid_tet_mesh(vol, cells=6)
    body, _ = tissue_fem_body(vol, nodes, tets, device=device)
    integral = float(CT_TISSUE(hu)[2].astype(float).sum()) * 1e-9  # 1 mm^3 voxels [m^3]
    assert body.mass.sum() == pytest.approx(integral, rel=0.01)


def _indentation(volume, press_at_x: float) -> float:
    """Mean downward displacement [m] of the top nodes within 3 mm of (press_at_x, centre)
    under 0.5 N spread over them; bottom nodes fixed; static K u = f."""
    nodes, tets = grid_tet_mesh(volume, cells=8)
    body, _ = tissue_fem_body(volume, nodes, tets)
    q = body.rest
    top = q[:, 2] > q[:, 2].max() - 1e-9
    centre_y = 0.5 * (q[:, 1].min() + q[:, 1].max())
    load = top & (np.hypot(q[:, 0] - press_at_x, q[:, 1] - centre_y) <= 3e-3 + 1e-9)
    fixed = q[:, 2] < q[:, 2].min() + 1e-9
    f = np.zeros_like(q)
    f[load, 2] = -0.5 / load.sum()
    free = np.repeat(~fixed, 3)
    k = body.stiffness_matrix().tocsr()[free][:, free]
    u = np.zeros(q.size)
    u[free] = spla.spsolve(k.tocsc(), f.ravel()[free])
    return -float(u.reshape(-1, 3)[load, 2].mean())


def test_the_dense_side_indents_less_and_layers_lie_between_the_homogeneous_blocks():
    n = 24
    soft = np.full((n, n, n), 40.0, np.float32)          # muscle: 20 kPa
    stiff = np.full((n, n, n), 300.0, np.float32)        # 1 MPa
    halves = soft.copy()
    halves[: n // 2] = 300.0                             # x < 12 mm dense
    layered = soft.copy()
    layered[:, :, n // 2:] = 300.0                       # the top half dense
    vol = lambda data: Volume(data, spacing=(1.0, 1.0, 1.0))  # noqa: E731
    left, right = 6e-3, 18e-3                             # press points over each half [m]
    for x in (left, right):  # the same point on every block (the 5-tet split is not mirror-symmetric)
        d_soft, d_stiff, d_halves = (_indentation(vol(data), x) for data in (soft, stiff, halves))
        assert d_stiff < d_halves < d_soft
    assert _indentation(vol(halves), left) < 0.1 * _indentation(vol(halves), right)  # dense under the left point
    assert _indentation(vol(stiff), left) < _indentation(vol(layered), left) < _indentation(vol(soft), left)
    # Linear elasticity: depth scales as 1/E for one material (the two have different nu: not exact).
    assert 10 < _indentation(vol(soft), left) / _indentation(vol(stiff), left) < 100


def test_bad_tables_are_named():
    with pytest.raises(Exception, match="poisson"):
        TissueTable((0.0, 1.0), (1e3, 1e4), (0.3, 0.5), (1000.0, 1000.0))
    with pytest.raises(Exception, match="intensity"):
        TissueTable((1.0, 0.0), (1e3, 1e4), (0.3, 0.3), (1000.0, 1000.0))
    e, nu, rho = CT_TISSUE([-2000.0, 40.0, 5000.0])
    assert e.tolist() == pytest.approx([1e3, 2e4, 1e7]) and rho[0] == pytest.approx(1.2)
