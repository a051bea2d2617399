"""The live window's mouse tool (softvr.app._drag_tool), moved here with it from examples.

Truth: a spring F = k m (target - point) with k = 400 1/s^2 pulls a grabbed point towards a
target 80 px above it: after 40 steps of 5 ms (0.2 s, longer than half the spring's period,
pi / sqrt(400) = 0.16 s) it has closed most of the gap and risen; releasing removes
the force.
"""

import numpy as np

from softvr.app._drag_tool import DragTool
from softvr.render import SurfaceRenderer
from softvr.scene import BUNDLED, load_scene


def test_the_mouse_tool_pulls_the_grabbed_body_towards_the_pointer(display):
    with load_scene(BUNDLED / "soft-cube.toml", frames=1) as ex:
        for _ in range(60):  # let it land
            ex.scene.step(ex.dt)
        with SurfaceRenderer(320, 240, ex.camera, bounds=ex.bounds, onscreen=True) as r:
            ex.setup_render(r)
            ex.update_render(r)
            r.render()
            tool = DragTool(ex.scene, r.vtk_renderer)
            assert tool.press(160, 120)
            start = tool.point()
            tool.move(160, 200)  # display y grows upwards
            assert tool.target[2] > start[2] + 0.05
            gap = np.linalg.norm(tool.target - start)
            for _ in range(40):
                tool.apply()
                ex.scene.step(ex.dt)
            assert np.linalg.norm(tool.target - tool.point()) < 0.6 * gap
            assert tool.point()[2] > start[2] + 0.02
            tool.release()
            assert ex.scene.external == {}
