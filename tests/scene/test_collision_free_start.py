"""The collision-free start of a scene (thesis 5.2.3): soft bodies that start crossing another
body are pushed out of it (``[simulation] collision_free_start = true``).

Truths: a soft cube sunk 10 mm into a table (a fixed box, top at z = 0.2 m) starts with every
surface point on or above the table top and its clamped nodes where the scene put them;
`softvr check` refuses the sunk cube without the option and accepts it with; of two
overlapping soft spheres the one with fewer tets moves, and afterwards none of its surface
points is inside the other (behind every face plane of its convex hull, by SciPy); two
rigid boxes cannot be pushed and are still reported, as is a ball sunk into a fixed mesh (an
obstacle, not a body).
"""

import numpy as np
from scipy.spatial import ConvexHull

from softvr.cli import main
from softvr.scene import load_scene

SUNK = '''format = "softvr-scene 1"
[simulation]
dt = 0.005
frames = 3
collision_free_start = {on}
[material.jelly]
young = 2e4
density = 1000.0
alpha = 1.0
[[plane]]
[[body]]
name = "table"
type = "fixed"
box = [0.4, 0.4, 0.2]
position = [0.0, 0.0, 0.1]
[[body]]
name = "jelly"
type = "fem"
box = [0.1, 0.1, 0.1]
cells = 4
material = "jelly"
position = [0.02, 0.0, 0.24]
fixed_above = 0.285
'''


def test_a_sunk_soft_cube_starts_on_the_table(tmp_path, capsys):
    path = tmp_path / "sunk.toml"
    path.write_text(SUNK.format(on="false"))
    assert main(["check", str(path)]) == 2
    assert "bodies 'table' and 'jelly'" in capsys.readouterr().err
    path.write_text(SUNK.format(on="true"))
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "'jelly' pushed out of 'table'" in out
    with load_scene(path) as example:
        jelly = example.bodies["jelly"]
        surface = example._drawn_by_name["jelly"].vertices()
        # Pushed out 1.5 margins (1e-4 m) past the top: on it, to the margin.
        assert surface[:, 2].min() >= 0.2 - 1e-6
        # The push moved the bottom up by the 10 mm it was sunk, and not the clamped top.
        assert 0.0095 < example.separation[0][2] < 0.012
        np.testing.assert_array_equal(jelly.q[jelly.fixed], jelly.rest[jelly.fixed])
        assert jelly.fixed.any()
        for _ in range(example.frames):
            record = example.step()
        assert record["max_penetration_m"] < 1e-3 and np.isfinite(jelly.q).all()


def test_of_two_soft_spheres_the_smaller_mesh_moves_out_of_the_other(tmp_path):
    path = tmp_path / "spheres.toml"
    path.write_text('''format = "softvr-scene 1"
[simulation]
collision_free_start = true
gravity = [0.0, 0.0, 0.0]
[material.gel]
young = 1e4
density = 1000.0
[[body]]
name = "big"
type = "fem"
sphere = 0.1
cells = 0.025
material = "gel"
[[body]]
name = "small"
type = "fem"
sphere = 0.05
cells = 0.025
material = "gel"
position = [0.13, 0.0, 0.0]
''')
    with load_scene(path) as example:
        big, small = example.bodies["big"], example.bodies["small"]
        assert len(small.tets) < len(big.tets)
        assert [(a, b) for a, b, _ in example.separation] == [("small", "big")]
        np.testing.assert_array_equal(big.q, big.rest)  # the obstacle stays put
        # The big sphere's surface is convex: a point is inside iff it is behind every face
        # plane of its hull (SciPy / Qhull). Nothing of the small sphere is inside it now.
        hull = ConvexHull(example._drawn_by_name["big"].vertices())
        points = example._drawn_by_name["small"].vertices()
        assert (points @ hull.equations[:, :3].T + hull.equations[:, 3]).max(axis=1).min() >= -1e-6


def test_rigid_bodies_that_cross_are_still_reported(tmp_path, capsys):
    path = tmp_path / "boxes.toml"
    path.write_text('''format = "softvr-scene 1"
[simulation]
collision_free_start = true
[material.wood]
density = 600.0
[[body]]
name = "left"
type = "rigid"
box = [0.2, 0.2, 0.2]
material = "wood"
position = [0.0, 0.0, 0.15]
[[body]]
name = "right"
type = "rigid"
box = [0.2, 0.2, 0.2]
material = "wood"
position = [0.15, 0.05, 0.2]
''')
    assert main(["check", str(path)]) == 2
    assert "bodies 'left' and 'right'" in capsys.readouterr().err


def test_a_body_crossing_a_fixed_mesh_is_reported(tmp_path, capsys):
    """A fixed mesh is an obstacle, not a body: a rigid ball sunk into it is still reported."""
    import trimesh

    trimesh.creation.box((0.4, 0.4, 0.2)).export(tmp_path / "table.obj")
    path = tmp_path / "ball.toml"
    path.write_text('''format = "softvr-scene 1"
[material.wood]
density = 600.0
[[body]]
name = "table"
type = "fixed"
mesh = "table.obj"
position = [0.0, 0.0, 0.1]
[[body]]
name = "ball"
type = "rigid"
sphere = 0.05
material = "wood"
position = [0.0, 0.0, 0.24]
''')
    assert main(["check", str(path)]) == 2
    assert "bodies 'ball' and 'table'" in capsys.readouterr().err
