"""The player's overlap (:attr:`softvr.app.Player.overlap`): the next frame's physics stepping on
a worker thread while this frame is drawn.

Truth: the sequential player (the same scene, each frame stepped, rasterized, then drawn, all on
one thread) - every frame's image and the body's node positions q after every frame must be the
same bit for bit, since the overlapped render draws only what the sequential one reads (the
surfaces moved to the frame before the step starts, the volume the rasterizer wrote) and the
steps run the same arithmetic in the same order. An error raised by a step on the worker thread
reaches :meth:`~softvr.app.Player.step` on the calling thread with the sequential player's message.

A frame's times (the records' ``step_ms``, ``render_ms``, ``wall_ms``, ``latency_ms``) against
stages whose wall time is known: a physics step and a render that sleep STEP_S and RENDER_S
(a sleep lets the other thread run, as Warp's launches do). Truth: sequential, a frame's wall is
STEP_S + RENDER_S; overlapped, after the first frame, max(STEP_S, RENDER_S) (the step ran beside
the previous render); either way the latency, input read to image, is STEP_S + RENDER_S, and
the frames' walls add up to the loop's time measured around it.

Warp's CPU launches are split over threads as in the trainer (softvr.device.launch refuses a
kernel that accumulates with atomics, which are plain read-modify-writes on the CPU: the ray
caster's stale-pixel rectangle is a union of per-box rectangles), while physics and render also
run on two threads at once.
"""

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from softvr import Scene
from softvr.app import Player, _player
from softvr.datasets import HEAD_CT_PATH
from softvr.dynamics import RigidBody
from softvr.errors import SimulationError
from softvr.scene import BUNDLED, SceneExample, read_scene
from softvr.sim import STAGES


def _played(overlap: bool) -> tuple[list, list, list]:
    """Palpation's quick variant played with and without the overlap: per frame the image, the
    head's q after the frame's step, and the thread its physics stepped on."""
    with SceneExample(read_scene(BUNDLED / "palpation.toml", ("quick",)), device="cpu") as player:
        assert not player.overlap  # off by default: it adds a render to the latency
        player.overlap = overlap
        threads: list[str] = []
        step = player.scene.step

        def traced(dt):
            threads.append(threading.current_thread().name)
            return step(dt)

        player.scene.step = traced
        images, qs = [], []
        while player.frame < player.frames:
            player.step()
            qs.append(np.array(player.volume.body.q))
            images.append(player.render())
        return images, qs, threads


@pytest.mark.skipif(not HEAD_CT_PATH.exists(), reason="head CT (Debian invesalius-examples) not installed")
def test_the_overlapped_palpation_draws_and_steps_every_frame_as_the_sequential_player():
    seq_images, seq_q, seq_threads = _played(False)
    images, qs, threads = _played(True)
    assert len(images) == len(seq_images) == 6
    main = threading.main_thread().name
    assert seq_threads == [main] * 6
    assert threads[0] == main and all(t.startswith("softvr-physics") for t in threads[1:])
    for frame, (a, b, qa, qb) in enumerate(zip(images, seq_images, qs, seq_q)):
        assert np.array_equal(qa, qb), f"frame {frame}: q differs by up to {np.abs(qa - qb).max()} m"
        assert np.array_equal(a, b), f"frame {frame}: {np.mean(np.any(a != b, axis=2)):.2%} of pixels differ"
    assert any(not np.array_equal(seq_images[0], im) for im in seq_images[1:])  # the press shows


class Falling(Player):
    """A 0.1 m sphere falling from 1 m; overlapped like a volume scene."""

    name = "free_fall"
    overlap = True

    def __init__(self):
        scene = Scene(gravity=(0.0, 0.0, -9.81))
        self.ball = RigidBody.sphere(0.1, 1000.0, position=(0.0, 0.0, 1.0), name="ball")
        scene.add_body(self.ball)
        super().__init__(scene, 0.01, 1, 4, 32, 24, bounds=(-1, 1, -1, 1, -1, 1.2))

    def penetration(self):
        return 0.0

    def setup_render(self, renderer):
        renderer.add_sphere(self.ball.position, 0.1)

    def update_render(self, renderer):
        pass


def _diverged_message(overlap: bool) -> str:
    with Falling() as player:
        player.overlap = overlap
        player.step()
        player.ball.v[2] = 1e4  # [m/s] past max_speed: the next step diverges
        player.render()
        with pytest.raises(SimulationError) as error:
            player.step()
        return str(error.value)


def test_an_error_of_a_step_on_the_worker_thread_is_raised_by_step_with_the_same_message():
    sequential = _diverged_message(False)
    assert sequential.startswith("ball: diverged at step 2")
    assert _diverged_message(True) == sequential


STEP_S, RENDER_S = 0.08, 0.04  # [s] the sleeping stages' wall times
#: [ms] what a frame's times may exceed their sleeps by (the sleeps' overshoot, a thread's wake-up
#: on a loaded machine); under RENDER_S, so that a render or step counted twice cannot pass.
SLACK_MS = 30.0


class _SleepingScene:
    """A scene whose step takes STEP_S of wall time."""

    bodies: list = []

    def __init__(self):
        self.time = 0.0
        self.stage_ms = dict.fromkeys(STAGES, 0.0)

    def step(self, dt):
        time.sleep(STEP_S)
        self.time += dt
        return SimpleNamespace()


class _SleepingRenderer:
    """A renderer whose render takes RENDER_S of wall time."""

    def __init__(self, width, height, *args, **kwargs):
        self.shape = (height, width, 3)

    def render(self):
        time.sleep(RENDER_S)
        return np.zeros(self.shape, np.uint8)

    def close(self):
        pass


class _Sleeping(Player):
    frame_measures = False

    def __init__(self):
        super().__init__(_SleepingScene(), 0.01, 1, 5, 8, 6)

    def setup_render(self, renderer):
        pass

    def update_render(self, renderer):
        pass


@pytest.mark.parametrize("overlap", [False, True])
def test_a_frames_wall_is_its_period_and_its_latency_the_input_to_image_time(monkeypatch, overlap):
    monkeypatch.setattr(_player, "SurfaceRenderer", _SleepingRenderer)
    with _Sleeping() as player:
        player.overlap = overlap
        start = time.perf_counter()
        while player.frame < player.frames:
            player.step()
            player.render()
        loop_ms = (time.perf_counter() - start) * 1e3
    step, render = STEP_S * 1e3, RENDER_S * 1e3
    period = max(step, render) if overlap else step + render
    m = player.metrics
    walls = [r["wall_ms"] for r in m]
    assert loop_ms - SLACK_MS < sum(walls) <= loop_ms  # the rest: the loop's own calls between the player's
    assert step + render <= walls[0] < step + render + SLACK_MS  # the first frame steps alone
    for r in m[1:]:  # a render's overshoot shortens the wait for the next step: either side
        assert abs(r["wall_ms"] - period) < SLACK_MS, r
    for r in m:
        assert step + render <= r["latency_ms"] < step + render + SLACK_MS, r
        assert step <= r["step_ms"] < step + SLACK_MS and render <= r["render_ms"] < render + SLACK_MS, r
