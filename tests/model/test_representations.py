"""Model creation (thesis 5.2.2) against geometry: volumes by the divergence theorem, a box's
exact signed distance, barycentric reconstruction, and hand-made crossing triangles."""

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.model.shapes import box_surface
from softvr.model.shapes import icosphere
from softvr.model import collision_mesh, dynamics_mesh, embed_surface, intersecting_triangle_pairs, nodes_near_surface


def enclosed_volume(v, t):
    p = v[t]
    return np.einsum("fi,fi->f", p[:, 0], np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])).sum() / 6.0


def closed(t):
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    return bool((np.unique(edges, axis=0, return_counts=True)[1] == 2).all())


def box_distance(p, lo, hi):
    """Exact signed distance to the box [lo, hi] (negative inside)."""
    c, h = (lo + hi) / 2, (hi - lo) / 2
    q = np.abs(p - c) - h
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


def test_collision_mesh_keeps_the_shape_within_the_budget():
    """A 5120-triangle sphere of radius 5 cm to ~500 triangles: still closed, its volume within
    3 % of the original's, every vertex within 3 % of the radius from the sphere (the quadric
    error metric places a merged vertex off the surface by up to a few sagittas of the new,
    ~1 cm edges: 0.25 mm each)."""
    unit, tris = icosphere(4)
    v = 0.05 * unit
    v2, t2 = collision_mesh(v, tris, 500)
    assert 450 <= len(t2) <= 550 and closed(t2)
    assert enclosed_volume(v2, t2) == pytest.approx(enclosed_volume(v, tris), rel=0.03)
    np.testing.assert_allclose(np.linalg.norm(v2, axis=1), 0.05, atol=0.03 * 0.05)
    same_v, same_t = collision_mesh(v, tris, 10_000)  # already below the budget: unchanged
    np.testing.assert_array_equal(same_t, tris)


def test_dynamics_mesh_keeps_the_tets_near_the_part_and_embeds_every_vertex():
    """An 8 x 8 x 4 cm box turned 45 degrees about z, at 1.5 cm cells. Every kept tet's centroid
    is within the tet's centroid-to-corner reach of the box (exact signed distance); every
    point of the box (random samples, and every surface vertex) lies in a kept tet, bound to
    one tet that reproduces it from its barycentric weights; the grid corners the turned box
    leaves empty are dropped."""
    half = np.array([0.04, 0.04, 0.02])
    turn = np.array([[np.cos(np.pi / 4), -np.sin(np.pi / 4), 0], [np.sin(np.pi / 4), np.cos(np.pi / 4), 0], [0, 0, 1]])
    v, t = box_surface(2 * half, 6)
    v = (v - half) @ turn.T
    nodes, tets = dynamics_mesh(v, t, 0.015)
    corners = nodes[tets]
    centroid = corners.mean(axis=1)
    reach = np.linalg.norm(corners - centroid[:, None], axis=2).max(axis=1)
    assert (box_distance(centroid @ turn, -half, half) <= reach + 1e-9).all()
    assert len(np.unique(tets)) == len(nodes)  # no unused node
    grid_cells = np.ceil((v.max(axis=0) - v.min(axis=0)) / 0.015 - 1e-9).prod()
    assert len(tets) < 5 * grid_cells * 0.85  # the empty corners are gone
    rng = np.random.default_rng(0)
    inside = rng.uniform(-half, half, (2000, 3)) @ turn.T
    for points in (inside, v):
        index, weights = embed_surface(nodes, tets, points)
        assert index.shape == (len(points),) and (weights >= -1e-9).all()
        np.testing.assert_allclose(np.einsum("pk,pkc->pc", weights, nodes[tets[index]]), points, atol=1e-12)


def test_nodes_near_surface_are_within_the_radius():
    lo, hi = np.zeros(3), np.full(3, 0.1)
    v, t = box_surface(hi - lo, 4)
    grid = np.stack(np.meshgrid(*[np.linspace(-0.05, 0.15, 11)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    near = nodes_near_surface(grid, v, t, 0.02)
    expected = np.flatnonzero(box_distance(grid, lo, hi) <= 0.02 + 1e-12)
    np.testing.assert_array_equal(near, expected)


def test_crossing_triangles_are_found():
    a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    through = np.array([[0.2, 0.2, -0.5], [0.3, 0.2, 0.5], [0.2, 0.3, 0.5]])  # pierces a
    above = through + [0.0, 0.0, 1.0]
    beside = through + [2.0, 0.0, 0.0]
    tri = np.array([[0, 1, 2]])
    assert intersecting_triangle_pairs(a, tri, through, tri).tolist() == [[0, 0]]
    assert len(intersecting_triangle_pairs(a, tri, above, tri)) == 0
    assert len(intersecting_triangle_pairs(a, tri, beside, tri)) == 0
    # Two overlapping spheres cross along their intersection circle, disjoint ones nowhere.
    unit, tris = icosphere(3)
    pairs = intersecting_triangle_pairs(unit, tris, unit + [1.0, 0.0, 0.0], tris)
    assert len(pairs) > 20
    mid = unit[tris[pairs[:, 0]]].mean(axis=1)
    np.testing.assert_allclose(mid[:, 0], 0.5, atol=0.15)  # near the plane x = 0.5
    assert len(intersecting_triangle_pairs(unit, tris, unit + [2.1, 0.0, 0.0], tris)) == 0
    with pytest.raises(InputError, match="surface b"):
        intersecting_triangle_pairs(unit, tris, unit, tris + 10_000)


def test_push_apart_leaves_no_crossing_triangles_on_a_case_that_starts_intersecting():
    """A soft 6 cm ball sunk 1 cm into a fixed 10 cm block: 0 crossing triangle pairs and no
    surface vertex inside afterwards (checked by the independent crossing test and the
    block's exact signed distance), with the deformation local: the ball's far side moves
    less than a fifth of the deepest push."""
    from softvr.model import push_apart

    unit, tris = icosphere(3)
    ball = 0.03 * unit + [0.0, 0.0, 0.02]  # bottom at -1 cm: 1 cm into the block below z = 0
    block_lo, block_hi = np.array([-0.05, -0.05, -0.1]), np.array([0.05, 0.05, 0.0])
    bv, bt = box_surface(block_hi - block_lo, 8)
    bv = bv + block_lo
    assert len(intersecting_triangle_pairs(ball, tris, bv, bt)) > 0
    nodes, tets = dynamics_mesh(ball, tris, 0.01)
    embedding = embed_surface(nodes, tets, ball)
    moved, report = push_apart(nodes, tets, embedding, tris, bv, bt, margin=2e-4)
    index, weights = embedding
    surface = np.einsum("pk,pkc->pc", weights, moved[tets[index]])
    assert report.clean and report.iterations < 20
    assert len(intersecting_triangle_pairs(surface, tris, bv, bt)) == 0
    assert box_distance(surface, block_lo, block_hi).min() >= 0.0
    shift = np.linalg.norm(moved - nodes, axis=1)
    top = nodes[:, 2] > 0.045
    assert shift.max() >= 0.01 and shift[top].max() < 0.2 * shift.max()


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".ply", ".glb"])
def test_part_meshes_load_from_every_format(tmp_path, suffix):
    """The pipeline reads OBJ, STL, PLY and glTF (binary) alike: the same closed box back."""
    import trimesh

    from softvr.model import load_mesh

    v, t = box_surface((0.1, 0.06, 0.04), 3)
    path = tmp_path / f"part{suffix}"
    trimesh.Trimesh(v, t).export(path)
    v2, t2 = load_mesh(path)
    assert len(t2) == len(t)
    assert enclosed_volume(v2, t2) == pytest.approx(0.1 * 0.06 * 0.04, rel=1e-6)
    with pytest.raises(InputError, match="part.obj"):
        (tmp_path / "part.obj").write_text("v 0 0 0\nf 1 1 1\n")
        load_mesh(tmp_path / "part.obj")
