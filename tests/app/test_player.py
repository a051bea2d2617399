"""softvr.app: the player's step order and time, its metrics against free fall, and the one
frames-to-files loop's files.

Truths: a body falling freely under g from rest, integrated by backward (or semi-implicit)
Euler with step h, has v_n = n g h and x_n = x_0 + g h^2 n (n + 1) / 2 after n steps (no contact,
no damping); the hooks of every sub-step run in :data:`softvr.app.STEP_ORDER`, the frame's
once after its last sub-step; a run of F frames writes a video of F frames and a sheet of
min(8, F) frames, named after the scene as the command line spells it.
"""

import json

import imageio.v3 as iio
import numpy as np
import pytest

from softvr import Scene
from softvr.app import STEP_ORDER, Player, out_folder, output_name, record
from softvr.dynamics import RigidBody

G = -9.81


class Falling(Player):
    """A 0.1 m sphere falling from 1 m, no ground; it records the hooks it is called through."""

    name = "free_fall"

    def __init__(self, frames: int = 4, steps_per_frame: int = 3, dt: float = 0.01):
        scene = Scene(gravity=(0.0, 0.0, G))
        self.ball = RigidBody.sphere(0.1, 1000.0, position=(0.0, 0.0, 1.0), name="ball")
        scene.add_body(self.ball)
        self.calls: list[str] = []
        super().__init__(scene, dt, steps_per_frame, frames, 64, 48, bounds=(-1, 1, -1, 1, -1, 1.2))

    def drive(self):
        self.calls.append("drive")

    def haptic_tick(self):
        self.calls.append("haptics")

    def sense(self, solution):
        # The physics ran just before: the scene's clock moved by one step.
        self.calls.append("physics" if self.scene.time > 0 else "no physics")
        self.calls.append("sense")

    def update_volume(self):
        self.calls.append("volume")
        return {}

    def frame_metrics(self):
        self.calls.append("metrics")
        return {"height_m": float(self.ball.position[2])}

    def penetration(self):
        return 0.0

    def setup_render(self, renderer):
        renderer.add_plane(size=2.0)
        self._handle = renderer.add_sphere(self.ball.position, 0.1)

    def update_render(self, renderer):
        pass


def test_hooks_run_in_the_declared_order_once_per_sub_step():
    with Falling(frames=2, steps_per_frame=3) as player:
        player.step()
        assert player.calls == list(STEP_ORDER) * 3 + ["volume", "metrics"]
        assert STEP_ORDER == ("drive", "haptics", "physics", "sense")


def test_free_fall_matches_the_closed_form_of_euler_steps():
    h, k, frames = 0.01, 3, 4
    with Falling(frames=frames, steps_per_frame=k, dt=h) as player:
        while player.frame < player.frames:
            player.step()
        n = np.arange(1, frames + 1) * k
        m = player.metrics
        np.testing.assert_allclose([r["sim_time_s"] for r in m], n * h, rtol=1e-12)
        np.testing.assert_allclose([r["height_m"] for r in m], 1.0 + G * h * h * n * (n + 1) / 2, rtol=1e-9)
        mass = player.ball.mass
        v = G * h * n
        np.testing.assert_allclose([r["kinetic_energy_j"] for r in m], 0.5 * mass * v ** 2, rtol=1e-9)
        assert [r["contacts"] for r in m] == [0] * frames
        assert player.fps == pytest.approx(1.0 / (h * k))


def test_record_writes_the_video_sheet_and_metrics_named_by_the_rule(tmp_path):
    frames = 3
    doc = record(Falling(frames=frames), tmp_path, progress=False, png_every=2)
    name = "free-fall"  # the rule: the name as the command line spells it
    assert output_name("free_fall") == name
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{name}.mp4", f"{name}_frames", f"{name}_metrics.json",
                                                        f"{name}_sheet.png"]
    assert len(list(iio.imiter(tmp_path / f"{name}.mp4"))) == frames
    assert sorted(p.name for p in (tmp_path / f"{name}_frames").iterdir()) == ["frame_00000.png", "frame_00002.png"]
    sheet = iio.imread(tmp_path / f"{name}_sheet.png")
    assert sheet.ndim == 3 and sheet.shape[1] >= 3 * 64  # three frames side by side
    saved = json.loads((tmp_path / f"{name}_metrics.json").read_text())
    assert saved["scene"] == name == doc["scene"] and len(saved["frames"]) == frames
    assert saved["summary"]["frames"] == frames and saved["summary"]["max_contacts"] == 0
    assert saved["summary"]["sim_time_s"] == pytest.approx(frames * 3 * 0.01)


def test_the_default_output_folder_is_one_per_scene(tmp_path):
    assert out_folder(None, "soft_cube").as_posix() == "softvr-out/soft-cube"
    assert out_folder(tmp_path, "soft_cube") == tmp_path


class Headless(Falling):
    """Falling played without frame measures: asking for the penetration is an error."""

    frame_measures = False

    def penetration(self):
        raise AssertionError("a player without frame measures reads no penetration")


def test_a_headless_player_without_frame_measures_steps_the_same_physics_and_records_timings():
    """``frame_measures = False`` (the benches): the same Euler free fall x_n = x_0 + g h^2 n (n + 1) / 2,
    the hooks still in their order, and the records hold the timings and the scene's own metrics only."""
    h, k, frames = 0.01, 3, 4
    with Headless(frames=frames, steps_per_frame=k, dt=h) as player:
        for _ in range(frames):
            player.step()
        n = np.arange(1, frames + 1) * k
        m = player.metrics
        np.testing.assert_allclose([r["height_m"] for r in m], 1.0 + G * h * h * n * (n + 1) / 2, rtol=1e-9)
        assert player.calls[: 4 * k + 2] == list(STEP_ORDER) * k + ["volume", "metrics"]
        assert set(m[0]) == {"frame", "sim_time_s", "step_ms", "stage_ms", "render_ms", "wall_ms", "height_m"}
