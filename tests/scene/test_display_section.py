"""The scene file's [display]: the screens a scene is shown on (softvr cave ... SCENE)."""

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.scene import read_scene

SCENE = '''format = "softvr-scene 1"
[simulation]
dt = 0.005
frames = 3
[display]
{display}
[material.jelly]
young = 5e4
[[plane]]
[[body]]
name = "jelly"
type = "fem"
box = [0.2, 0.2, 0.2]
cells = 2
material = "jelly"
position = [0.0, 0.0, 0.15]
'''


def test_cave_preview_takes_the_scenes_display(tmp_path):
    from PIL import Image

    from softvr.cave.command import main

    path = tmp_path / "jelly.toml"
    path.write_text(SCENE.format(display='preset = "cube"'))
    assert read_scene(path).display == "cube"
    assert main(["preview", str(path), "--frames", "2", "--out", str(tmp_path / "a"), "--quiet"]) == 0
    assert main(["preview", "cube", str(path), "--frames", "2", "--out", str(tmp_path / "b"), "--quiet"]) == 0
    a = np.asarray(Image.open(tmp_path / "a" / "cave_preview.png"))
    b = np.asarray(Image.open(tmp_path / "b" / "cave_preview.png"))
    np.testing.assert_array_equal(a, b)  # the same five screens, the same two frames
    # A display named on the command line wins over the file's.
    assert main(["preview", "single-wall", str(path), "--frames", "2", "--out", str(tmp_path / "c"), "--quiet"]) == 0
    assert np.asarray(Image.open(tmp_path / "c" / "cave_preview.png")).shape != a.shape


def test_a_display_file_is_loaded_and_checked(tmp_path):
    from softvr.cave.display import preset, save_display

    save_display(preset("powerwall-2x2"), tmp_path / "wall.toml")
    path = tmp_path / "scene.toml"
    path.write_text(SCENE.format(display='file = "wall.toml"'))
    assert read_scene(path).display == str((tmp_path / "wall.toml").resolve())
    (tmp_path / "broken.toml").write_text('format = "softvr-display 1"\n')
    for display, field in (('preset = "dome"', "display.preset"), ('file = "missing.toml"', "display.file"),
                           ('file = "broken.toml"', "display.file"), ('preset = "cube"\nfile = "wall.toml"', "display")):
        path.write_text(SCENE.format(display=display))
        with pytest.raises(InputError, match=field.replace(".", r"\.")):
            read_scene(path)


def test_without_a_display_the_cave_command_says_what_is_missing(tmp_path):
    from softvr.cave.command import main

    path = tmp_path / "plain.toml"
    path.write_text(SCENE.format(display="").replace("[display]\n", ""))
    with pytest.raises(InputError, match=r"DISPLAY.*no \[display\] section"):
        main(["preview", str(path)])


def test_a_volume_scene_is_not_streamed_to_render_nodes_yet():
    from softvr.cave.command import make_source

    with pytest.raises(InputError, match=r"\[volume\] is not streamed"):
        make_source("palpation.toml", 2)
