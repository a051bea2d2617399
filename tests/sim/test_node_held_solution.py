"""A step's solution on the node arrays keeps its own step's contacts while later steps run
(the stepper reads them in its arrays until the next step would write them, then copies them
out for a solution that is still held).

Truth: the geometry the test sets. A soft cube's bottom face rests over the plane z = 0; a
point-plane contact is made at the start of the step, at the collision point's position x0
there (the contact's ``point_a``) with gap = z0 (the point's height over the plane) and the
plane's normal (0, 0, 1). Before each later step the cube is moved sideways, so the next
step's contacts are at other points. Positions are assigned and copied exactly; the gap is one
subtraction of a double: tolerance 1e-15 m.
"""

import numpy as np

from softvr import Scene
from softvr.collision import Plane
from softvr.contact.pgs import pushing_normals
from softvr.dynamics import Material

from tests.sim.test_node_rigid import _rigid_box
from tests.sim.test_node_surfaces import _add_with_surface, _block

GAP = 0.0  # [m] the cube's bottom over the plane at the start: resting on it
DT = 0.005  # [s]


def _bottom(q: np.ndarray) -> np.ndarray:
    """The bottom face's nodes [9, 3] [m] of a 2-cell cube at ``q``, sorted by (x, y)."""
    low = q[q[:, 2] < q[:, 2].min() + 1e-9]
    return low[np.lexsort((low[:, 1], low[:, 0]))]


def _plane_contacts(solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(point_a [c, 3], gap [c], normal [c, 3]) of the solution's contacts, sorted by (x, y)."""
    (contacts,) = solution.contacts
    order = np.lexsort((contacts.point_a[:, 1], contacts.point_a[:, 0]))
    return contacts.point_a[order], contacts.gap[order], contacts.normal[order]


def test_a_held_solution_keeps_its_steps_contacts_while_later_steps_run():
    scene = Scene(gravity=(0.0, 0.0, -9.81), friction=0.5)
    cube = _block(2, 0.1, (0.0, 0.0, 0.05 + GAP), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2))
    _add_with_surface(scene, cube)
    scene.add_plane(Plane(friction=0.5))
    starts, held = [], []
    for k, shift in enumerate([(0.0, 0.0, 0.0), (0.3, 0.0, 0.0), (0.0, 0.3, 0.0), (-0.2, 0.1, 0.0)]):
        cube.q = cube.q + np.asarray(shift)  # a new array: the stepper copies it in before the step
        starts.append(_bottom(cube.q))
        held.append(scene.step(DT))
        assert type(scene._stepper).__name__ == "NodeStepper"
        if k == 0:
            held[0].impulses  # read before the next step: its contacts built on the step's arrays
    for start, solution in zip(starts, held):
        point, gap, normal = _plane_contacts(solution)
        assert point.shape == (9, 3)
        np.testing.assert_allclose(point, start, rtol=0, atol=1e-15)
        np.testing.assert_allclose(gap, start[:, 2], rtol=0, atol=1e-15)
        np.testing.assert_array_equal(normal, np.tile([0.0, 0.0, 1.0], (9, 1)))
        assert np.all(solution.impulses[0][:, 0] > 0)  # the plane holds the cube up at every step


def test_pushing_normals_of_a_box_resting_on_a_soft_cube_point_from_what_holds_it_up():
    """ContactSolution.pushing_normals: normals of the body's pushing contacts (normal impulse
    > 0), from the other side towards it. A rigid box rests on a soft cube resting on the floor:
    every normal pushing the box is +z (the cube's top face below it, whichever side the contact
    has the box on), every one pushing the cube +z from the floor or -z from the box, in the
    contact sets' order (thesis 5.4: what a haptic tool's stiffness blocks). The box's corners dent
    the cube's top by ~2e-3 rad (0.35 N on a 5e4 Pa cube): tolerance 1e-2. Read both ways: from the step's arrays
    before anything else is read, and after the contacts were built."""
    scene = Scene(gravity=(0.0, 0.0, -9.81), friction=0.5)
    cube = _block(2, 0.1, (0.0, 0.0, 0.05), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2))
    _add_with_surface(scene, cube)
    scene.add_plane(Plane(friction=0.5))
    _rigid_box(scene, (0.03, 0.03, 0.01), 500.0, (0.0, 0.0, 0.11))
    for _ in range(5):
        solution = scene.step(DT)
    assert type(scene._stepper).__name__ == "NodeStepper"
    first = [solution.pushing_normals(body) for body in (0, 1)]  # before the contacts are built
    # The per-object path's definition over the built sets (softvr.contact.pgs.pushing_normals).
    sets = solution.set_bodies()
    expected = [pushing_normals(sets, solution.impulses, solution.frames, body) for body in (0, 1)]
    for body, normals in enumerate(first):
        assert len(normals) >= 4, body  # the box's corners or the cube's top face's nodes at least
        np.testing.assert_array_equal(normals, expected[body])
        np.testing.assert_array_equal(solution.pushing_normals(body), expected[body])  # from the built contacts
    box = first[1]
    np.testing.assert_allclose(box, np.tile([0.0, 0.0, 1.0], (len(box), 1)), atol=1e-2)
    up, down = first[0][first[0][:, 2] > 0], first[0][first[0][:, 2] < 0]
    assert len(up) + len(down) == len(first[0]) and len(up) >= 4 and len(down) >= 1
    np.testing.assert_allclose(np.abs(first[0]), np.tile([0.0, 0.0, 1.0], (len(first[0]), 1)), atol=1e-2)
