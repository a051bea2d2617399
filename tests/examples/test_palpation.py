"""The palpation demo on a synthetic CT: a ball of soft tissue (40 HU, r 14 mm) around a
bone core (1500 HU, r 6 mm) in air, 1 mm voxels.

Truths: the bone core's tets are clamped (denser than 1150 kg/m^3); the FEM's mass is the
voxel integral of the table's density (within voxelization, 3 %); under the press the
deformed CT differs from the rest CT (by more than 100 HU) only near the probe (within the
contact patch plus two mesh cubes of the press point, 18 mm; nothing in the far half of the
ball), and the rendered frame only within that distance of the press point's projection;
when the probe has withdrawn the tissue relaxes back; the skin surface of the deformed label
volume moves in by about the indentation at the press point.
"""

import numpy as np
import pytest

from softvr.model import CT_TISSUE
from softvr.volume import Volume


@pytest.fixture(scope="module")
def ball_ct():
    n = 40
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1)
    r = np.linalg.norm(ijk - 19.5, axis=-1)
    hu = np.where(r < 6.0, 1500.0, np.where(r < 14.0, 40.0, -1000.0)).astype(np.int16)
    labels = np.where(r < 6.0, 2, np.where(r < 14.0, 1, 0)).astype(np.uint8)
    return Volume(hu, spacing=(1.0, 1.0, 1.0)), Volume(labels, spacing=(1.0, 1.0, 1.0), is_label=True)


def _project(renderer, point_mm):
    from vtkmodules.vtkRenderingCore import vtkCoordinate

    c = vtkCoordinate()
    c.SetCoordinateSystemToWorld()
    c.SetValue(*point_mm)
    x, y = c.GetComputedDisplayValue(renderer.vtk_renderer)
    return x, renderer.vtk_renderer.GetRenderWindow().GetSize()[1] - 1 - y  # image rows run down


#: The press point [mm] on the ball's skin that the palpation demo's rule picks (the most anterior
#: tissue voxel 15 % of the ball's width beside the first most anterior one, at its height),
#: worked out by hand from the ball's definition: the most anterior voxels have y = 33
#: (13.5 mm from the centre), the first of them in index order is (16, 33, 19) ((i - 19.5)^2 +
#: (k - 19.5)^2 < 14^2 - 13.5^2 = 13.75); the tissue spans x = 6 .. 33, so 15 % of it is 4 voxels
#: beside it: x = 20, whose column at z = 19 ends at y = 33.
PRESS = np.array([20.0, 33.0, 19.0])


def _ball_scene(folder, ct, labels, *, frames: int, radius: float, depth: float, dt: float) -> str:
    """The palpation demo's scene over the synthetic CT: its [volume] as palpation.toml's (the
    labels too), the probe keyed on the demo's press, 2 mm off the skin to ``depth`` past it
    (sin^2 over the run) at every step's time."""
    from softvr.volume import save

    save(ct, folder / "ball.nrrd")
    save(labels, folder / "labels.nrrd")
    times = np.arange(frames + 1) * dt
    travel = (depth + 0.002) * np.sin(np.pi * times / times[-1]) ** 2
    target = PRESS * 1e-3
    keys = np.array([[target[0], target[1] + radius + 0.002 - s, target[2]] for s in travel]).tolist()
    return f"""format = "softvr-scene 1"
[simulation]
dt = {dt}
steps_per_frame = 1
frames = {frames}
gravity = [0.0, 0.0, 0.0]
friction = 0.4
contact_margin = 0.001
[render]
size = [96, 96]
camera = "front"
elevation = 5.0
zoom = 1.3
[volume]
file = "ball.nrrd"
labels = "labels.nrrd"
name = "ball"
cells = [8, 8, 8]
render_step = 1
sample_distance = 1.0
[[body]]
name = "probe"
type = "kinematic"
sphere = {radius}
subdivisions = 2
position = {keys[0]}
[body.motion]
times = {times.tolist()}
positions = {keys}
"""


def test_palpating_a_synthetic_ct(ball_ct, tmp_path):
    from softvr.scene import load_scene

    ct, labels = ball_ct
    radius = 0.005
    (tmp_path / "ball.toml").write_text(_ball_scene(tmp_path, ct, labels, frames=8, radius=radius, depth=0.003,
                                                    dt=0.01))
    with load_scene(tmp_path / "ball.toml") as ex:  # the camera looks at the pressed side (+y) head on
        body, probe = ex.bodies["ball"], ex.bodies["probe"]

        def indentation():  # [m] how far the probe's front is past the rest skin point
            return PRESS[1] * 1e-3 - (probe.position[1] - radius)

        rest_volume = ex.volume.deformed.data.copy()
        rest_image = ex.render()
        rest_skin = ex.volume.label_surface(1)[0] / 1e-3
        assert body.fixed.any()
        voxels = float(CT_TISSUE(ct.data)[2].astype(float).sum()) * 1e-9
        assert body.mass.sum() == pytest.approx(voxels, rel=0.03)
        while ex.frame < 4:  # the deepest point of the press is half way
            ex.step()
        pressed_image = ex.render()
        assert indentation() > 0.001
        press = PRESS
        # Far away the shell moves by micrometres: boundary voxels change by a few HU there.
        changed = np.argwhere(np.abs(ex.volume.deformed.data.astype(int) - rest_volume) > 100)
        assert len(changed) > 20
        # Contact patch radius sqrt(2 R d) ~ 5.5 mm, plus two 5 mm mesh cubes (the tets of the
        # moved nodes reach one cube further), plus a voxel: 18 mm. The far half of the ball
        # (its centre is 13.5 mm behind the skin point) does not change.
        assert np.linalg.norm(changed - press, axis=1).max() < 18.0
        assert changed[:, 1].min() > 19.5
        diff = np.abs(pressed_image.astype(int) - rest_image.astype(int)).max(axis=2) > 24
        rows, cols = np.nonzero(diff)
        assert len(rows) > 0
        x, y = _project(ex.renderer, press * 1e-3)
        side = _project(ex.renderer, (press + (18.0, 0.0, 0.0)) * 1e-3)  # the volume bound, seen head on
        assert np.hypot(cols - x, rows - y).max() < np.hypot(side[0] - x, side[1] - y)
        skin = ex.volume.label_surface(1)[0] / 1e-3
        near = np.linalg.norm(rest_skin - press, axis=1) < 2.0
        moved_in = press[1] - skin[np.linalg.norm(skin[:, [0, 2]] - press[[0, 2]], axis=1) < 1.5][:, 1].max()
        assert near.any() and 0.5 * indentation() / 1e-3 < moved_in < 1.5 * indentation() / 1e-3 + 1.0
        while ex.frame < ex.frames:
            ex.step()
        assert np.abs(body.q - body.rest).max() < 0.5e-3  # relaxed after the probe left


def test_the_live_view_plays_a_volume_scene_in_a_window(ball_ct, display, tmp_path):
    """``softvr view palpation`` plays palpation.toml through the one window loop; here the same
    kind of scene over the synthetic CT: every frame played, the probe pressing the ball's skin."""
    from softvr.app import play_window
    from softvr.scene import load_scene
    from softvr.volume import save

    save(ball_ct[0], tmp_path / "ball.nrrd")
    (tmp_path / "ball.toml").write_text(f"""format = "softvr-scene 1"
[simulation]
dt = 0.01
frames = 5
gravity = [0.0, 0.0, 0.0]
[render]
size = [96, 96]
[volume]
file = "{(tmp_path / 'ball.nrrd').as_posix()}"
name = "ball"
unit = 0.001
cells = [8, 8, 8]
threshold = -300.0
[[body]]
name = "probe"
type = "kinematic"
sphere = 0.005
position = [0.0195, 0.0385, 0.0195]
[body.motion]
times = [0.0, 0.05]
positions = [[0.0195, 0.0385, 0.0195], [0.0195, 0.0325, 0.0195]]
""")
    with load_scene(tmp_path / "ball.toml") as player:
        assert play_window(player, timeout_s=10.0) == 5  # a volume frame is slow on a loaded CPU
        # The ball's skin (r 14 mm about 19.5 mm) is at y = 33.5 mm; the probe's front goes 6 mm past
        # it, at rest at the start: the tissue under it must have moved.
        ball = player.bodies["ball"]
        assert np.linalg.norm(ball.q - ball.rest, axis=1).max() > 0.5e-3
