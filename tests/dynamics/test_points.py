"""Point entities: p = f(q), p_dot = J v, F_q = J^T F_p (thesis 5.1.2).

Truths: finite differences of p = f(q) along v (J is the exact derivative, up to O(h)),
virtual work F . (J v) = (J^T F) . v, and barycentric reproduction of the embedded points.
"""

import numpy as np
import pytest

from softvr.dynamics import FemBody, Material
from softvr.dynamics.points import EmbeddedPoints, embed_in_tets
from softvr.errors import InputError
from softvr.volume import Volume, grid_tet_mesh


def _soft_box():
    spacing = np.array([0.05, 0.05, 0.05])
    nodes, tets = grid_tet_mesh(Volume(np.zeros((3, 3, 3), np.uint8), spacing=spacing, origin=spacing / 2), 3)
    return FemBody(nodes, tets, Material(1e5, 0.3, 1000.0)), nodes, tets


def test_embedding_reproduces_points_and_follows_the_body():
    body, nodes, tets = _soft_box()
    rng = np.random.default_rng(0)
    pts = rng.uniform(0.0, 0.15, size=(200, 3))
    tet_index, w = embed_in_tets(nodes, tets, pts)
    assert (w >= -1e-9).all() and np.allclose(w.sum(axis=1), 1.0)
    emb = EmbeddedPoints(body, tets[tet_index], w)
    np.testing.assert_allclose(emb.positions(), pts, atol=1e-12)
    # An affine motion of the nodes moves embedded points by the same affine map.
    a = np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 1.0]])
    body.q = nodes @ a.T + [0.3, -0.1, 0.2]
    np.testing.assert_allclose(emb.positions(), pts @ a.T + [0.3, -0.1, 0.2], atol=1e-12)


def test_embedded_jacobian_is_the_derivative_and_its_transpose_maps_forces():
    body, nodes, tets = _soft_box()
    rng = np.random.default_rng(1)
    pts = rng.uniform(0.01, 0.14, size=(30, 3))
    emb = EmbeddedPoints(body, *(lambda ti, w: (tets[ti], w))(*embed_in_tets(nodes, tets, pts)))
    v = rng.normal(size=body.q.shape)
    j = emb.jacobian()
    np.testing.assert_allclose(j @ v.ravel(), emb.velocities(v).ravel(), atol=1e-12)
    h = 1e-6
    p0 = emb.positions()
    body.q = body.q + h * v
    np.testing.assert_allclose((emb.positions() - p0) / h, emb.velocities(v), atol=1e-6)
    f = rng.normal(size=(30, 3))
    assert np.dot(f.ravel(), j @ v.ravel()) == pytest.approx(np.dot(emb.generalized_forces(f).ravel(), v.ravel()))


def test_points_outside_the_mesh_are_rejected_by_index():
    body, nodes, tets = _soft_box()
    with pytest.raises(InputError, match=r"points\[1\].*outside"):
        embed_in_tets(nodes, tets, [[0.05, 0.05, 0.05], [0.5, 0.5, 0.5]])
    with pytest.raises(InputError, match=r"weights\[0\]"):
        EmbeddedPoints(body, [[0, 1, 2, 3]], [[0.5, 0.5, 0.5, 0.5]])
