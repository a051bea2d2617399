"""Implicit adhesion (thesis ch. 4) on the whole-scene node arrays: FEM blocks glued to an
adhesive plane, stepped by :class:`softvr.sim._node_step.NodeStepper` (the arrays' sweeps with
the bounds of eq. 4.16, bonding / debonding of 4.3.3), checked against the model's closed-form
limits (docs/adhesion.md).

The blocks are 4 cm cubes of a stiff tissue (E = 200 kPa: under the debonding traction p* =
sqrt(W C) = 3.2 kPa they strain 1.6 %, so the interface traction stays close to uniform, as
the area-based prediction assumes), stepped at 1 ms.
"""

from __future__ import annotations

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.collision.contacts import unpack_keys
from softvr.contact import Adhesion
from softvr.dynamics import EmbeddedPoints, FemBody, Material
from softvr.scene import bundled, load_scene
from softvr.sim import node_model_supported
from softvr.sim._node_step import NodeStepper
from softvr.volume import Volume, grid_tet_mesh
from softvr.volume.tetmesh import boundary_faces

G = 9.81  # [m/s^2]
EDGE = 0.04  # block edge [m]
DT = 0.001  # [s]
GLUE = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)  # p* = sqrt(W C) = 3162 Pa
TISSUE = Material(2e5, 0.3, 1000.0, alpha=0.0, beta=1e-2)


def _add_block(scene, size: float, cells: int, corner, glue: Adhesion, clamped: bool = False) -> FemBody:
    """An FEM cube of edge ``size`` [m] (``cells`` grid cells a side) with its lowest corner at
    ``corner`` [3] [m], its boundary nodes as collision points and boundary faces as its
    surface; ``clamped``: its bottom nodes fixed."""
    spacing = np.full(3, size / cells)
    nodes, tets = grid_tet_mesh(Volume(np.zeros((cells,) * 3, np.uint8), spacing=spacing,
                                       origin=spacing / 2 + np.asarray(corner, float)), cells)
    body = FemBody(nodes, tets, TISSUE, fixed=nodes[:, 2] < corner[2] + 1e-9 if clamped else None,
                   name=f"block at {tuple(corner)}")
    faces = boundary_faces(body.tets)
    used = np.unique(faces)
    local = np.full(len(body.q), -1)
    local[used] = np.arange(len(used))
    scene.add_body(body, collision_points=EmbeddedPoints(body, used[:, None], np.ones((len(used), 1))),
                   collision_triangles=local[faces], adhesion=glue)
    return body


def _glued_blocks(cells: int, centres_x=(0.0,), glue: Adhesion = GLUE, steps: int = 20) -> tuple[Scene, list]:
    """FEM cubes (``cells`` grid cells a side) resting on an adhesive plane z = 0, their
    boundary nodes as collision points and boundary faces as surfaces, bonded over ``steps``."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5, contact_margin=0.002)
    blocks = [_add_block(scene, EDGE, cells, (x - EDGE / 2, -EDGE / 2, 0.0), glue) for x in centres_x]
    scene.add_plane(Plane(friction=0.5), adhesion=glue)
    for _ in range(steps):
        scene.step(DT)
    assert isinstance(scene._stepper, NodeStepper)  # on the node arrays, not per object
    return scene, blocks


def _bottom_area(scene, body_index: int) -> float:
    """Sum of the contact areas [m^2] of one body's contacts with the plane."""
    return sum(float(c.area.sum()) for c in scene.last_solution.contacts if c.b is None and c.a.body == body_index)


def _pull(scene, index: int, body: FemBody, force) -> None:
    """A force [3] [N] on the body, shared by its nodes as their mass (a uniform body force: no
    moment, and a uniform traction on a rigid interface)."""
    scene.external[index] = (body.mass / body.mass.sum())[:, None] * np.asarray(force, float)


def _pull_off(scene, block: FemBody, predicted: float, index: int = 0) -> float:
    """The upward force [N] (body ``index``'s, growing 12 N/s) at which ``block`` lifts 1 mm off
    (at most twice ``predicted`` [N])."""
    z0 = block.q[:, 2].mean()
    force = 0.0
    while block.q[:, 2].mean() < z0 + 0.001:  # lifted 1 mm: off
        force += 12.0 * DT
        _pull(scene, index, block, (0.0, 0.0, force))
        scene.step(DT)
        assert force < 2.0 * predicted, "never came off"
    return force


def _bonds(scene, index: int) -> dict:
    """Intensities of body ``index``'s tracked contacts, by key."""
    state = scene.adhesion_state.intensity
    keys = np.array(list(state), np.int64)
    mine = keys[unpack_keys(keys)["body_a"] == index] if len(keys) else keys
    return {int(k): state[int(k)] for k in mine}


@pytest.mark.parametrize("cells", [2, 3, 4])
def test_fem_block_pulls_off_at_its_weight_plus_area_times_sqrt_w_c(cells):
    """A bonded contact debonds once its traction reaches p* = sqrt(W C beta^3) (eq. 4.12 with
    the traction law of eq. 4.10, beta = 1): a block pulled by a slowly growing uniform body
    force F lifts off at F* = m g + A sqrt(W C), with A the bottom face's area. The contact
    areas are the surface around each bottom vertex projected on the plane (docs/adhesion.md),
    so they sum to the face's L^2 at every resolution (0.1 %: the face sags by micrometres).

    Tolerance 15 %: the ramp (12 N/s) goes on during the debonding runaway (eq. 4.12 at eta =
    1e-3 J s/m^2 takes ~20 ms once the traction passes p* by a few %: +0.24 N, 4 %), and the
    block's compliance concentrates the traction at its rim (a rigid punch's is singular
    there), so that the rim lets go first: a few % below F* at 1.6 % strain (5-10 % at a
    quarter of this stiffness)."""
    scene, (block,) = _glued_blocks(cells)
    area = _bottom_area(scene, 0)
    assert area == pytest.approx(EDGE**2, rel=1e-3)
    predicted = block.mass.sum() * G + EDGE**2 * GLUE.traction_limit()
    force = _pull_off(scene, block, predicted)
    assert isinstance(scene._stepper, NodeStepper)
    assert force == pytest.approx(predicted, rel=0.15)
    assert not _bonds(scene, 0) or max(_bonds(scene, 0).values()) < 0.5  # its bonds gave


def test_tearing_one_block_off_leaves_the_others_bond_intact():
    """Two blocks bonded to one adhesive plane; one is torn off by a force 1.5 times its F*.
    The other's interface carries only its weight, a compression: with no bonding rate and no
    traction, eqs. 4.11-4.12 leave its intensities at exactly 1, and its bonded bottom nodes stay
    where they bonded (to 1 um; the block above them still settles under its weight by tens of
    um: rho g L^2 / (2 E) = 39 um)."""
    scene, (torn, kept) = _glued_blocks(2, centres_x=(-0.04, 0.04))
    before = _bonds(scene, 1)
    assert len(before) == 9 and all(b == 1.0 for b in before.values())  # its 3 x 3 bottom vertices
    q0 = kept.q.copy()
    force = 1.5 * (torn.mass.sum() * G + EDGE**2 * GLUE.traction_limit())
    _pull(scene, 0, torn, (0.0, 0.0, force))
    for _ in range(100):
        scene.step(DT)
    assert torn.q[:, 2].min() > 0.005  # torn off, 5 mm up
    assert not _bonds(scene, 0)  # its contacts are forgotten past the debond gap
    after = _bonds(scene, 1)
    assert after.keys() == before.keys() and all(b == 1.0 for b in after.values())
    bottom = q0[:, 2] < 1e-6
    assert np.abs(kept.q[bottom] - q0[bottom]).max() < 1e-6  # held where they bonded


def test_an_adhesion_state_held_across_steps_keeps_its_steps_bonds():
    """``Scene.adhesion_state`` is read from the arrays' carried table when first used; one
    held unread while later steps tear the block off (1.5 times its F* = m g + A sqrt(W C))
    is still its own step's: the 3 x 3 bottom vertices bonded at exactly 1 (eqs. 4.11-4.12
    under a compression), not the torn block's none."""
    scene, (block,) = _glued_blocks(2)
    held = scene.adhesion_state
    _pull(scene, 0, block, (0.0, 0.0, 1.5 * (block.mass.sum() * G + EDGE**2 * GLUE.traction_limit())))
    for _ in range(100):
        scene.step(DT)
    assert block.q[:, 2].min() > 0.005 and not scene.adhesion_state.intensity  # torn off, bonds forgotten
    assert len(held.intensity) == 9 and all(b == 1.0 for b in held.intensity.values())


def _shear(scene, block: FemBody, force: float) -> float:
    """Push the block sideways along x by ``force`` [N], shared by its bottom nodes (the
    interface's plane: no moment that would tip it), for 0.2 s; its largest mean x shift [m]."""
    bottom = block.q[:, 2] < 1e-6
    nodes = np.zeros_like(block.q)
    nodes[bottom, 0] = force / bottom.sum()
    scene.external[0] = nodes
    x0 = block.q[:, 0].mean()
    shift = 0.0
    for _ in range(200):
        scene.step(DT)
        shift = max(shift, abs(block.q[:, 0].mean() - x0))
    assert isinstance(scene._stepper, NodeStepper)
    return shift


def test_bonded_block_holds_a_sideways_force_below_its_limit():
    """Tangentially a bond is a spring of A C beta^2 on its slip (docs/adhesion.md), which holds
    up to the debonding traction p* (past it a pressed bond slides, one under traction tears):
    the interface holds F < A sqrt(W C) = 5.06 N. At F = 0.5 A sqrt(W C) the springs stretch
    F / (A C) = 0.16 mm (plus the block's shear, 0.1 mm more at most: F L / (G A) with G =
    E / 2.6 = 77 kPa), so the block moves less than 1 mm."""
    scene, (block,) = _glued_blocks(2)
    assert _shear(scene, block, 0.5 * EDGE**2 * GLUE.traction_limit()) < 1e-3
    assert min(_bonds(scene, 0).values()) == 1.0


def test_bonded_block_slides_under_a_sideways_force_above_its_limit():
    """At F = 1.5 A sqrt(W C), past the limit of every bond (and far past friction, mu m g =
    0.3 N), the bonds slide or tear: an unbalanced force of at least F - A sqrt(W C) = 2.5 N on
    64 g moves the block by centimetres within 0.2 s."""
    scene, (block,) = _glued_blocks(2)
    assert _shear(scene, block, 1.5 * EDGE**2 * GLUE.traction_limit()) > 0.01


def test_adhesion_moves_between_the_arrays_and_the_per_object_path_by_key():
    """Scene.adhesion_state carries the bonds by contact key when a scene leaves the node arrays
    and when it comes back. New contacts start at beta0 = 0.2 and bond under the block's weight
    (eq. 4.11: r (c - beta p0) with c = m g / A = 392 Pa, p0 = 100 Pa, r = 0.1 / (Pa s): some
    30 / s) to 1 within 0.1 s; a bond the other path did not receive would start again at 0.2
    and grow by 0.03 a step. So after a step on each path every bond is still at exactly 1, and
    the block then holds 90 % of its F* (m g + A sqrt(W C beta^3), beta = 1) at the gap of the
    traction law. Tolerance 10 %: the traction is uniform only to the few % of the pull-off
    test, and the ramp leaves an oscillation of period 2 pi sqrt(m / (A C)) = 13 ms, damped by
    the block's Rayleigh damping."""
    glue = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3, bonding_rate=0.1, saturation=100.0, initial=0.2)
    scene, (block,) = _glued_blocks(2, glue=glue, steps=150)
    bonded = _bonds(scene, 0)
    assert len(bonded) == 9 and all(b == 1.0 for b in bonded.values())
    scene.node_arrays = False
    scene.step(DT)
    assert scene._stepper is None
    assert _bonds(scene, 0) == bonded
    scene.node_arrays = True
    scene.step(DT)
    assert isinstance(scene._stepper, NodeStepper)
    assert _bonds(scene, 0) == bonded
    bottom = block.q[:, 2] < 1e-6
    hold = 0.9 * (block.mass.sum() * G + EDGE**2 * glue.traction_limit())
    for n in range(300):  # ramped over 0.2 s (a sudden load would overshoot twice as far), then held
        _pull(scene, 0, block, (0.0, 0.0, hold * min(n / 200, 1.0)))
        scene.step(DT)
    # Held below p*, the bonds stretch by the traction law's gap g = p / (C beta^2) (eq. 4.10).
    gap = (hold - block.mass.sum() * G) / (EDGE**2 * glue.stiffness)
    assert block.q[bottom, 2].mean() == pytest.approx(gap, rel=0.1)
    assert _bonds(scene, 0) == bonded


@pytest.mark.parametrize("name", ["probe.toml", "lips.toml"])
def test_bundled_adhesive_fem_scenes_step_on_the_arrays(name):
    """probe.toml (a kinematic probe on tacky tissue) and lips.toml (two FEM lips of mucosa)
    are FEM scenes with adhesion: held by the node arrays, and not declined by their sweep
    count (their physics: tests/examples/test_examples.py)."""
    player = load_scene(bundled(name), frames=1, width=16, height=16)
    assert node_model_supported(player.scene)
    with player:
        player.step()
    assert isinstance(player.scene._stepper, NodeStepper)


def test_bonds_between_bodies_stay_detected_until_the_debond_gap():
    """A bond stretches by the traction law's gap g = p / (C beta^2) (eq. 4.10) and is forgotten
    only past ``debond_gap`` (4.3.3), so detection between two surfaces must reach that far,
    not just the scene's contact margin (1 mm). A 2 cm FEM block bonded on top of a clamped
    4 cm one (no gravity; C = 1e5 N/m^3, so that the gap is millimetres), pulled up by a force
    ramped to F = 0.16 N: the bonded patch is its bottom face, A = 4 cm^2 (one way of the
    vertex-triangle contacts bonds it, the upper block's 9 bottom vertices: test_two_fem_blocks_
    glued_face_to_face_pull_apart_at_the_patch_area_times_sqrt_w_c), a traction of 400 Pa
    (below p* = sqrt(W C) = 1 kPa) and a gap of F / (A C) = 4 mm, inside the debond gap of 1 cm.
    Were the bonds dropped at 1 mm, nothing would hold the block: it would fly off. Tolerance
    10 %: the mean over the last 84 ms, one period 2 pi sqrt(m / (A C)) of the ringing the ramp
    leaves (undamped: the block's Rayleigh damping does not act on its motion on the bonds), and
    the uneven traction."""
    glue = Adhesion(stiffness=1e5, max_energy=10.0, viscosity=1e-3, debond_gap=0.01)
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.5, contact_margin=0.001)
    _add_block(scene, EDGE, 2, (-EDGE / 2, -EDGE / 2, 0.0), glue, clamped=True)
    upper = _add_block(scene, EDGE / 2, 2, (-EDGE / 4, -EDGE / 4, EDGE), glue)
    bottom = upper.q[:, 2] < EDGE + 1e-9
    # Pressed on while it bonds (10 % of F): laid exactly on, its contacts' gaps are the detection's
    # round-off (-0.9 nm), and which of them carry load then depends on how far the sweeps
    # converged (main: 10 bonds at tolerance 1e-5 and 1e-9, 9 at 1e-7).
    _pull(scene, 1, upper, (0.0, 0.0, -0.016))
    for _ in range(10):
        scene.step(DT)
    bonded = dict(scene.adhesion_state.intensity)
    assert len(bonded) == 10 and all(b == 1.0 for b in bonded.values())
    force, area = 0.16, (EDGE / 2) ** 2
    gaps = []
    for n in range(300):
        _pull(scene, 1, upper, (0.0, 0.0, force * min(n / 200, 1.0)))
        scene.step(DT)
        gaps.append(upper.q[bottom, 2].mean() - EDGE)
    assert isinstance(scene._stepper, NodeStepper)
    assert np.mean(gaps[-84:]) == pytest.approx(force / (area * glue.stiffness), rel=0.1)
    assert scene.adhesion_state.intensity.keys() == bonded.keys()


@pytest.mark.parametrize("arrays", [True, False], ids=["node arrays", "per object"])
def test_two_fem_blocks_glued_face_to_face_pull_apart_at_the_patch_area_times_sqrt_w_c(arrays):
    """Two equal FEM blocks (4 cm, 3 cells a side) glued face to face, the lower one's bottom
    clamped, the upper one pulled up by a uniform body force ramped at 12 N/s: the bonded patch
    is their common face, A = L^2, and the upper block lets go at F* = m g + A sqrt(W C) (eqs.
    4.10, 4.12 at beta = 1, as on the plane: docs/adhesion.md; thesis ch. 4). Vertex-triangle
    contacts are made both ways there (the upper's vertices on the lower's triangles and the
    lower's on the upper's), each way's vertex areas tiling the patch: only one way may bond.
    (Both ways, each at the smaller of its vertex's and its triangle's area, it let go at 3.97 N
    of 5.69: the rim's contacts, where each block's vertices sit on the other's edges, take a
    side face's normal and count no area.)

    Tolerance 10 %, as for the block on the plane (its 15 % is for the softer, coarser cases):
    the ramp goes on during the debonding runaway (~20 ms at eta = 1e-3 J s/m^2: +0.24 N, 4 %),
    and the compliance concentrates the traction at the rim, which lets go a few % early. Both
    paths: the node arrays' and the per-object path's (``node_arrays`` off), one rule
    (:func:`softvr.contact._adhesion_kernels.yields_patch`)."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5, contact_margin=0.002, node_arrays=arrays)
    _add_block(scene, EDGE, 3, (-EDGE / 2, -EDGE / 2, 0.0), GLUE, clamped=True)
    upper = _add_block(scene, EDGE, 3, (-EDGE / 2, -EDGE / 2, EDGE), GLUE)
    for _ in range(20):  # rest and bond
        scene.step(DT)
    predicted = upper.mass.sum() * G + EDGE**2 * GLUE.traction_limit()
    force = _pull_off(scene, upper, predicted, index=1)
    assert isinstance(scene._stepper, NodeStepper) == arrays
    assert force == pytest.approx(predicted, rel=0.1)


def test_the_parallel_evolve_keeps_the_one_thread_evolves_bonds_and_table():
    """The evolve with a thread per contact (a GPU's form: bonds evolved per contact, the keys
    radix-sorted, the table written in key order) against the one-thread evolve it replaces (the
    obviously correct reference: each contact in turn, insertion-sorted by key) on the adhesive
    candy pile after 40 steps (bonded, debonding and untracked contacts): the same intensities,
    slips and carried table, bit for bit."""
    example = load_scene(bundled("candy-adhesive.toml"), frames=1, width=64, height=48, haptics=False)
    scene = example.scene
    dt = 0.008
    for _ in range(40):
        scene.step(dt)
    adhesion = scene._stepper.adhesion
    ad, c = adhesion.arrays, scene._stepper.state.contacts
    names = ("intensity", "carried_count", "carried_key", "carried_impulse", "carried_intensity", "carried_slip")
    before = {name: getattr(ad, name).numpy().copy() for name in names}
    slip = c.slip.numpy().copy()
    results = []
    for parallel in (False, True):
        for name, value in before.items():
            getattr(ad, name).assign(value)
        c.slip.assign(slip)
        adhesion.parallel = parallel
        _, evolve = adhesion.record(dt)
        evolve[0]()
        results.append({**{name: getattr(ad, name).numpy().copy() for name in names}, "slip": c.slip.numpy().copy()})
    n = int(c.count.numpy()[0])
    assert int(results[0]["carried_count"][0]) == n > 0
    assert (results[0]["intensity"][:n] > 0).sum() >= 10  # bonded contacts
    for name in (*names, "slip"):
        np.testing.assert_array_equal(results[1][name], results[0][name], err_msg=name)
