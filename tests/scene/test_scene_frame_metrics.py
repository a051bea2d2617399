"""The box stack's frame metrics, read off the rigid arrays it steps on, against closed forms:
a box pushed a known depth into the ground, the potential energy of boxes held still, the
contacts of five flat interfaces."""

import numpy as np
import pytest

from softvr.scene import bundled, load_scene
from softvr.sim.frame_metrics import rigid_stepper

G = 9.81
MASS = 500.0 * 0.2 * 0.2 * 0.1  # pine boxes of 0.2 x 0.2 x 0.1 m [kg]


def test_box_stack_metrics_come_off_the_arrays_and_match_the_closed_forms():
    with load_scene(bundled("box-stack.toml"), frames=2) as example:
        record = example.step()
        assert rigid_stepper(example.scene) is not None
        # Five flat interfaces (ground and four box on box), four corners each.
        assert record["contacts"] == 20
        box = example.bodies["box 0"]
        box.position = np.array([0.0, 0.0, 0.04])  # half height 5 cm: 1 cm into the ground
        box.orientation = np.array([1.0, 0.0, 0.0, 0.0])  # (the frame left it tilted by ~1e-6 rad)
        assert example.penetration() == pytest.approx(0.01, rel=0, abs=1e-12)
        heights = []
        for b in example.scene.bodies:
            b.v = np.zeros(6)
            heights.append(b.position[2])
        kinetic, energy = example.energies()
        assert kinetic == 0.0
        assert energy == pytest.approx(MASS * G * sum(heights), rel=1e-12)
