"""Tet meshes in VTK files (softvr.model.tet_files): the legacy format written by hand from
the VTK file-format specification is the independent truth."""

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.model import load_tet_mesh, save_tet_mesh
from softvr.volume import Volume, grid_tet_mesh

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


def test_legacy_file_reads_as_written(tmp_path):
    path = tmp_path / "two.vtk"
    path.write_text(LEGACY_TWO_TETS)
    nodes, tets = load_tet_mesh(path)
    np.testing.assert_array_equal(nodes, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
    np.testing.assert_array_equal(tets, [[0, 1, 2, 3], [4, 3, 2, 1]])


def test_round_trip_of_a_grid_mesh(tmp_path):
    nodes, tets = grid_tet_mesh(Volume(np.zeros((3, 2, 2), np.uint8), spacing=(0.01, 0.01, 0.01)), (3, 2, 2))
    path = save_tet_mesh(tmp_path / "grid.vtu", nodes, tets)
    q, t = load_tet_mesh(path)
    np.testing.assert_array_equal(q, nodes)
    np.testing.assert_array_equal(t, tets)


def test_a_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "mesh.vtu"
    path.write_text("old")
    with pytest.raises(InputError, match="tets"):
        save_tet_mesh(path, np.zeros((4, 3)), [[0, 1, 2, 7]])
    assert path.read_text() == "old"


def test_cells_that_are_not_tets_are_named(tmp_path):
    path = tmp_path / "mixed.vtk"
    # The second cell a triangle (VTK type 5).
    path.write_text(LEGACY_TWO_TETS.replace("CELLS 2 10\n4 0 1 2 3\n4 4 3 2 1", "CELLS 2 9\n4 0 1 2 3\n3 4 3 2")
                    .replace("10\n10\n", "10\n5\n"))
    with pytest.raises(InputError, match=r"cells\[1\].*tetrahedra only.*cell type 5") as err:
        load_tet_mesh(path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("name, found", [("missing.vtu", "no file"), ("mesh.obj", "'.obj'")])
def test_bad_paths(tmp_path, name, found):
    with pytest.raises(InputError, match=found):
        load_tet_mesh(tmp_path / name)
