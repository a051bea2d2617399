"""A scene's own contact-solve tolerance (``Scene.pgs_tolerance``, the scene file's
``[simulation] pgs_tolerance``) against Hooke's law.

A held tool at rest on a clamped soft block: what the hand feels (the tool's virtual coupling,
thesis 5.4) must be the block's elastic force, E A delta / L, within what the looser stop
allows. The shoulder scenes stop their sweeps at 3e-4 m/s (docs/physics-core.md, session 11).
"""

from __future__ import annotations

import numpy as np

from softvr import Scene
from softvr.dynamics import Coupling, FixedBody, Material, RigidPoints
from tests.sim.test_node_rigid import _rigid_box
from tests.sim.test_node_surfaces import _add_with_surface, _block

#: The shoulder scenes' stop [m/s] (scenes/shoulder.toml, scenes/shoulder-arthroscopy.toml).
SHOULDER_TOLERANCE = 3e-4


def test_a_tool_resting_on_a_clamped_block_at_the_shoulders_tolerance_feels_hookes_force():
    """A 86 g rigid plate (12 x 12 x 2 cm) pulled down by a 200 N/m coupling onto the whole top
    face of a 10 cm FEM cube (E 1e5 Pa, Poisson 0, bottom clamped, frictionless), no gravity.
    With Poisson 0 the clamp adds no lateral stress, so the column is uniaxial and linear tets
    are exact: the block pushes back F = E A delta / L (Hooke), delta the top face's mean
    descent, L = 0.1 m, A = 0.01 m^2 (k_b = 1e4 N/m). The hand feels F_c = k_c (stretch).
    Tolerance: the stop ends the sweeps once every velocity is within T of eq. 5.5's
    solution, so at rest an imbalance dF between the coupling and the block may survive if the
    exact step would move the pressed column by no more than T: from eq. 5.2,
    v = dt dF / (M + dt^2 K), so dF <= T (M / dt + dt K), with M the plate and block masses
    (0.086 + 1 kg) and K = k_c + k_b: 3e-4 (108.6 + 102) = 0.063 N of F ~ 1.96 N (3 %)."""
    dt, k_c, young, size = 0.01, 200.0, 1e5, 0.1
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.0, pgs_tolerance=SHOULDER_TOLERANCE)
    block = _block(2, size, (0.0, 0.0, -size / 2), Material(young, 0.0, 1000.0, alpha=0.0, beta=1e-2),
                   fixed=lambda x: x[:, 2] < -size + 1e-6)
    _add_with_surface(scene, block)
    half = np.array([0.06, 0.06, 0.01])
    plate = _rigid_box(scene, half, 300.0, (0.0, 0.0, half[2] + 0.0005), name="plate")
    anchor = FixedBody(position=(0.0, 0.0, 2 * half[2] - 0.01), name="handle")  # 1 cm below the plate's top
    scene.add_body(anchor)
    coupling = Coupling(RigidPoints(plate, [[0.0, 0.0, half[2]]]), RigidPoints(anchor, [[0.0, 0.0, 0.0]]), k_c,
                        damping=2.0)
    scene.add_coupling(coupling)
    top = np.flatnonzero(block.q[:, 2] > -1e-6)
    rest = block.q[top, 2].copy()
    for _ in range(150):
        solution = scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    hand = k_c * coupling.stretch()[0, 2]  # [N] the coupling pulls the plate down with it
    delta = float(np.mean(rest - block.q[top, 2]))  # [m]
    hooke = young * size ** 2 * delta / size
    bound = SHOULDER_TOLERANCE * ((plate.mass + 1000.0 * size ** 3) / dt + dt * (k_c + young * size))
    assert 1.5 < hand < 2.5 and delta > 0.0  # pressed: ~k_c 1 cm, less the block's share
    assert abs(hand - hooke) <= bound, (hand, hooke, bound, solution.iterations)
    assert np.abs(plate.v[:3]).max() <= SHOULDER_TOLERANCE  # at rest within the stop
