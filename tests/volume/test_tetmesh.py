"""Embedding meshes: the 5-tet grid is conforming, positively oriented and tiles the footprint."""

from collections import Counter

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.volume import Volume, check_tets, grid_tet_mesh, load_tet_mesh
from softvr.volume.tetmesh import tet_signed_volumes


def _faces(tets):
    return Counter(tuple(sorted(f)) for t in tets for f in (t[[1, 2, 3]], t[[0, 2, 3]], t[[0, 1, 3]], t[[0, 1, 2]]))


@pytest.mark.parametrize("cells", [1, 2, (3, 2, 4)])
def test_grid_mesh_tiles_the_footprint_and_conforms(cells):
    vol = Volume(np.zeros((7, 6, 9), np.uint8), spacing=(0.5, 1.0, 2.0), origin=(1, 2, 3))
    nodes, tets = grid_tet_mesh(vol, cells)
    c = np.broadcast_to(cells, 3)
    assert len(tets) == 5 * np.prod(c)
    vols = tet_signed_volumes(nodes, tets)
    assert (vols > 0).all()
    # The tets tile the footprint box exactly: their volumes add up to its volume.
    assert vols.sum() == pytest.approx(np.prod(np.array(vol.shape) * vol.spacing), rel=1e-12)
    assert np.allclose(nodes.min(0), vol.origin - vol.spacing / 2)
    # Conforming: interior faces are shared by exactly two tets; the boundary has 2 triangles per square.
    counts = Counter(_faces(tets).values())
    assert set(counts) <= {1, 2}
    assert counts[1] == 4 * (c[0] * c[1] + c[1] * c[2] + c[0] * c[2])


def test_grid_mesh_with_mask_keeps_cubes_touching_it():
    vol = Volume(np.zeros((16, 16, 16), np.float32))
    vol.data[2:5, 2:5, 2:5] = 1.0
    # Cubes of 4 voxels span -0.5..3.5 (voxels 0-3) and 3.5..7.5 (voxels 4-7): voxels 2-4
    # touch cubes 0 and 1 along each axis, so 8 cubes are kept.
    for kw in ({"threshold": 0.5}, {"mask": vol.data > 0}):
        nodes, tets = grid_tet_mesh(vol, 4, **kw)
        assert len(tets) == 5 * 8 and (tet_signed_volumes(nodes, tets) > 0).all()
        assert np.allclose(nodes.min(0), -0.5) and np.allclose(nodes.max(0), 7.5)


def test_left_handed_direction_still_gives_positive_tets():
    vol = Volume(np.zeros((4, 4, 4), np.uint8), direction=np.diag([1.0, -1.0, 1.0]))
    nodes, tets = grid_tet_mesh(vol, 2)
    assert (tet_signed_volumes(nodes, tets) > 0).all()


def test_bad_meshes_are_rejected_by_name():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    with pytest.raises(InputError, match=r"tets\[1\].*inverted"):
        check_tets(nodes, [[0, 1, 2, 3], [0, 2, 1, 3]])
    with pytest.raises(InputError, match=r"tets\[0\].*degenerate"):
        check_tets(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], float), [[0, 1, 2, 3]])
    with pytest.raises(InputError, match=r"tets\[0\].*node indices in \[0, 4\]"):
        check_tets(nodes, [[0, 1, 2, 9]])
    bad = nodes.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match=r"nodes\[3\].*finite"):
        check_tets(bad, [[0, 1, 2, 3]])
    with pytest.raises(InputError, match="cells"):
        grid_tet_mesh(Volume(np.zeros((3, 3, 3))), 0)


def test_user_mesh_round_trips_through_meshio(tmp_path):
    import meshio

    vol = Volume(np.zeros((5, 5, 5), np.uint8))
    nodes, tets = grid_tet_mesh(vol, 2)
    path = tmp_path / "m.vtu"
    meshio.write(path, meshio.Mesh(nodes, [("tetra", tets[:, [0, 2, 1, 3]])]))
    with pytest.raises(InputError, match="inverted"):
        load_tet_mesh(path)
    n2, t2 = load_tet_mesh(path, fix_orientation=True)
    assert np.allclose(n2, nodes) and (tet_signed_volumes(n2, t2) > 0).all()
    meshio.write(tmp_path / "tri.vtu", meshio.Mesh(nodes, [("triangle", tets[:, :3])]))
    with pytest.raises(InputError, match="tetra"):
        load_tet_mesh(tmp_path / "tri.vtu")
    with pytest.raises(InputError, match="no such file"):
        load_tet_mesh(tmp_path / "missing.vtu")


def test_boundary_faces_close_the_box_and_point_outward():
    from softvr.volume import boundary_faces

    vol = Volume(np.zeros((6, 5, 4), np.uint8), spacing=(1.0, 2.0, 0.5))
    nodes, tets = grid_tet_mesh(vol, (3, 2, 2))
    faces = boundary_faces(tets)
    assert len(faces) == 4 * (3 * 2 + 2 * 2 + 3 * 2)  # 2 triangles per boundary square
    p = nodes[faces]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    outward = (p.mean(axis=1) - nodes.mean(axis=0)) * normals
    assert (outward.sum(axis=1) > 0).all()
    # Divergence theorem: the closed outward surface encloses the box's volume.
    enclosed = np.einsum("fi,fi->f", p[:, 0], normals).sum() / 6.0
    assert enclosed == pytest.approx(np.prod(np.array(vol.shape) * vol.spacing))
    # Every boundary edge is shared by exactly two boundary triangles (a closed surface).
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()
    with pytest.raises(InputError, match="tets"):
        boundary_faces(np.zeros((3, 3), int))


# Two tets sharing the face (1, 2, 3), in the legacy ASCII format of "VTK File Formats"
# (POINTS, CELLS with a count before each cell, CELL_TYPES 10 = VTK_TETRA).
LEGACY_TWO_TETS = """# vtk DataFile Version 3.0
two tets
ASCII
DATASET UNSTRUCTURED_GRID
POINTS 5 double
0 0 0
1 0 0
0 1 0
0 0 1
1 1 1
CELLS 2 10
4 0 1 2 3
4 4 3 2 1
CELL_TYPES 2
10
10
"""


def test_a_legacy_vtk_file_written_by_hand_reads_as_written(tmp_path):
    path = tmp_path / "two.vtk"
    path.write_text(LEGACY_TWO_TETS)
    nodes, tets = load_tet_mesh(path)
    np.testing.assert_array_equal(nodes, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
    np.testing.assert_array_equal(tets, [[0, 1, 2, 3], [4, 3, 2, 1]])


@pytest.mark.parametrize("suffix", [".vtu", ".msh"])
def test_save_tet_mesh_round_trips(tmp_path, suffix):
    from softvr.volume import save_tet_mesh

    nodes, tets = grid_tet_mesh(Volume(np.zeros((4, 3, 3), np.uint8), spacing=(0.01, 0.01, 0.01)), (3, 2, 2))
    path = save_tet_mesh(tmp_path / f"grid{suffix}", nodes, tets)
    q, t = load_tet_mesh(path)
    np.testing.assert_allclose(q, nodes, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(t, tets)


def test_a_failed_save_keeps_the_old_file(tmp_path):
    from softvr.volume import save_tet_mesh

    path = tmp_path / "mesh.vtu"
    path.write_text("old")
    with pytest.raises(InputError, match="tets"):
        save_tet_mesh(path, np.zeros((4, 3)), [[0, 1, 2, 7]])
    assert path.read_text() == "old"
