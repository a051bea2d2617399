"""Parts files of ``softvr build-model`` that are broken or hostile (issue 17).

Truth: the requirement — an InputError whose source is the parts file and whose message names
the field (``part[0].mesh``); no TypeError / AttributeError / ValueError from inside the
reader, nothing opened that is not a regular file, no grid allocated beyond the stated limit
(softvr.model.representations.MAX_GRID_TETS).
"""

import os

import pytest
import trimesh

from softvr.errors import InputError
from softvr.model import build_model, read_parts

_PART = '[[part]]\nname = "ball"\nmesh = "ball.ply"\nkind = "soft"\n'


@pytest.fixture
def folder(tmp_path):
    trimesh.creation.icosphere(2, radius=0.02).export(tmp_path / "ball.ply")
    os.mkfifo(tmp_path / "fifo.ply")
    return tmp_path


def _parts(folder, text):
    path = folder / "parts.toml"
    path.write_text('format = "softvr-parts 1"\n' + text)
    return path


@pytest.mark.parametrize("text, field", [
    ("part = 1.5\n", "part"),
    ("part = [1, 2]\n", "part"),
    ("defaults = [1]\n" + _PART, "defaults"),
    (_PART.replace('"soft"', '["soft"]'), "part[0].kind"),
    (_PART.replace('"ball"', '"' + "b" * 300 + '"', 1), "part[0].name"),
    (_PART.replace('"ball.ply"', '"ba\\u0000ll.ply"'), "part[0].mesh"),
    (_PART.replace('"ball.ply"', '"' + "m" * 300 + '.ply"'), "part[0].mesh"),
    (_PART.replace('"ball.ply"', '"fifo.ply"'), "part[0].mesh"),
    (_PART + "cell_size = 1e-9\n", "part[0].cell_size"),
    (_PART + "collision_triangles = 1000000000\n", "part[0].collision_triangles"),
    (_PART + '[[coupling]]\na = ["ball"]\nb = "ball"\nradius = 0.01\nstiffness = 1.0\n', "coupling[0].a"),
    (_PART + '[[coupling]]\na = "ball"\nb = "x"\nnodes = [99999999999]\nstiffness = 1.0\n', "coupling[0].nodes"),
    ("coupling = 7\n" + _PART, "coupling"),
])
def test_a_broken_parts_file_is_refused_naming_the_field(folder, text, field):
    path = _parts(folder, text)
    with pytest.raises(InputError) as caught:
        read_parts(path)
    assert caught.value.source == str(path)
    assert field in str(caught.value), str(caught.value)


def test_a_cell_size_that_would_need_millions_of_tets_is_refused_naming_the_part(folder):
    """A 4 cm ball in 0.2 mm cubes: 8e6 cubes, refused before the grid is allocated."""
    path = _parts(folder, _PART + "cell_size = 0.0002\n")
    with pytest.raises(InputError) as caught:
        build_model(path, progress=False)
    assert caught.value.source == str(path)
    assert "part[0] (ball).cell_size" in str(caught.value) and "tets" in str(caught.value)


def test_a_typo_in_a_key_of_every_table_of_a_parts_file_is_refused_at_once(folder):
    """Every table of the format (softvr.model.parts' docstring: the top, [defaults], [[part]],
    [[coupling]]) with a misspelt key: one error naming each by its field path and the key
    meant (written here by hand from the docstring); a part's own key under [defaults] (its
    name) is refused there, once, not on every part."""
    path = _parts(folder, 'fromat = 1\n[defaults]\ncel_size = 0.01\nname = "all"\n' + _PART + "densty = 900.0\n"
                  + _PART.replace('"ball"', '"cap"', 1) + "fricton = 0.3\n"
                  + '[[coupling]]\na = "ball"\nb = "cap"\nradius = 0.01\nstiffness = 1.0\ncolide = true\n')
    with pytest.raises(InputError) as caught:
        read_parts(path)
    assert caught.value.problems == [
        ("fromat", "a known key (did you mean 'format'?)", "'fromat'"),
        ("defaults.cel_size", "a known key (did you mean 'cell_size'?)", "'cel_size'"),
        ("defaults.name", "one of alpha, beta, cell_size, collision_triangles, density, friction, kind, poisson, "
         "young", "'name' (a key of each [[part]])"),
        ("part[0].densty", "a known key (did you mean 'density'?)", "'densty'"),
        ("part[1].fricton", "a known key (did you mean 'friction'?)", "'fricton'"),
        ("coupling[0].colide", "a known key (did you mean 'collide'?)", "'colide'")]
