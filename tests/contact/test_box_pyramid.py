"""Rigid box primitives of different sizes in contact, against analytic geometry.

Truths. A stack of boxes at rest carries each box on the top face of the one below: the
bottom face of box i (its lowest corner, z_i - h_i when level) lies at the top of box i - 1
(its highest corner, the ground z = 0 under the first), and the rest height of box i is the
sum of the heights below it plus its half height, z_i = sum_{k<i} 2 h_k + h_i. A passive
contact does no positive work, so the mechanical energy E = sum_i (1/2 m_i |v_i|^2 +
1/2 w_i . I_i w_i + m_i g z_i) never rises above its start. Two crossed edges are closest at
the common perpendicular of their lines: the gap is the distance between those lines. The
contact areas of a manifold sum to the area of the face patch it stands for: a box's bottom
face on a plane, the overlap rectangle of a small box centred on a big one.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane, box_corners, box_vs_box, box_vs_plane
from softvr.collision.contacts import ContactKind, unpack_keys
from softvr.dynamics import RigidBody
from softvr.dynamics.rigid import quat_from_rotvec, quat_multiply

G, DENSITY, DT = 9.81, 500.0, 1.0 / 60.0


def _stack(edges, gap=1e-4):
    """Cubes of the given edge lengths [m] stacked centred on the ground, ``gap`` [m] apart."""
    scene = Scene(friction=0.6)
    scene.add_plane(Plane(friction=0.6))
    boxes, z = [], 0.0
    for i, edge in enumerate(edges):
        z += gap
        box = RigidBody.box((edge,) * 3, DENSITY, position=(0.0, 0.0, z + edge / 2), name=f"box {i}")
        scene.add_body(box, collision_box=(edge / 2,) * 3)
        boxes.append(box)
        z += edge
    return scene, boxes


def _energy(boxes):
    return sum(b.kinetic_energy() + b.mass * G * b.position[2] for b in boxes)


def _penetrations(boxes, edges):
    """Depth [m] of each box below the top of what it rests on (> 0: penetration): the top of
    box i - 1 (its highest corner; the ground z = 0 under box 0) minus the bottom of box i (its
    lowest corner)."""
    tops = [0.0] + [box_corners(b, (e / 2,) * 3)[:, 2].max() for b, e in zip(boxes[:-1], edges[:-1])]
    bottoms = [box_corners(b, (e / 2,) * 3)[:, 2].min() for b, e in zip(boxes, edges)]
    return np.array(tops) - np.array(bottoms)


@pytest.mark.parametrize("edges", [(0.4, 0.3, 0.2, 0.1), (0.1, 0.2)], ids=["pyramid", "inverted"])
def test_boxes_of_different_sizes_rest_on_each_other(edges):
    """A pyramid of cubes (0.4, 0.3, 0.2, 0.1 m) and a 0.2 m cube on a 0.1 m one rest 3 s at
    dt = 1/60 s.

    Penetration below 1 mm at every step: a missed contact lets a box fall g dt^2 = 2.7 mm in
    one step, so a box without support fails at once. Energy: E(t) <= E(0) (1 + 1e-9). The
    boxes start at rest and only fall (closing the 0.1 mm gaps: E drops by sum m_i g times
    the gaps below box i, 0.07 J of the pyramid's 172 J), contacts do no positive work, and
    semi-implicit Euler loses 1/2 m g^2 dt^2 per free-falling step; the 1e-9 relative bound
    is the round-off allowance, 1e3 times the 1e-16 relative error of summing E and 1e-6 of
    what a box sinking through a missed contact gains back when it is pushed out (the old
    corner-only contacts gained 0.36 J). Rest heights within 1 mm of z_i = sum_{k<i} e_k +
    e_i / 2 (the start gaps, 0.1 mm each, close; the rest is the solver's tolerance).
    """
    scene, boxes = _stack(edges)
    e0 = _energy(boxes)
    deepest, highest = -np.inf, -np.inf
    for _ in range(180):
        scene.step(DT)
        deepest = max(deepest, _penetrations(boxes, edges).max())
        highest = max(highest, _energy(boxes))
    assert deepest < 1e-3
    assert highest <= e0 * (1 + 1e-9)
    rest = np.cumsum(edges) - np.asarray(edges) / 2
    np.testing.assert_allclose([b.position[2] for b in boxes], rest, rtol=0, atol=1e-3)


def _box(half, position, *turns):
    """A box body of half extents ``half`` [3] [m] at ``position`` [m], turned by each of
    ``turns`` in order: (world axis 0-2, angle [rad])."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for axis, angle in turns:
        q = quat_multiply(quat_from_rotvec(angle * np.eye(3)[axis]), q)
    return RigidBody.box(2 * np.asarray(half), DENSITY, position=position, orientation=q)


@pytest.mark.parametrize("height", [-1e-3, 0.0, 2e-3])
def test_crossed_edges_meet_at_the_distance_between_their_lines(height):
    """Box b (half extents 0.1, 0.07, 0.05) turned 45 deg about y has its top edge (its body
    corner x < 0, z > 0) along y on the line x_b = (0.05 - 0.1) / sqrt 2, z_b = (0.1 + 0.05) /
    sqrt 2; box a (0.06, 0.08, 0.04), turned 45 deg about x and then 60 deg about z, has its
    bottom edge horizontal along (cos 60, sin 60, 0), its middle placed at m = (x_b + 0.02,
    -0.01, z_b + ``height``). The two lines are horizontal and not parallel, so their distance
    is the height difference ``height``, their common perpendicular is vertical, and it
    stands where a's line crosses x = x_b, at y = m_y + (x_b - m_x) tan 60 (inside both
    edges). The gap must equal ``height``, the normal be +z and the point the middle of the
    perpendicular, all to round-off (1e-12 m), as one edge-edge contact (the faces' separating
    axes all overlap more here; corner-face contacts alone report none at all).
    """
    hb, ha = np.array([0.1, 0.07, 0.05]), np.array([0.06, 0.08, 0.04])
    x_b, top_b = (hb[2] - hb[0]) / np.sqrt(2), (hb[0] + hb[2]) / np.sqrt(2)
    b = _box(hb, (0.0, 0.0, 0.0), (1, np.pi / 4))
    middle = np.array([x_b + 0.02, -0.01, top_b + height])
    a = _box(ha, (0.0, 0.0, 0.0), (0, np.pi / 4), (2, np.pi / 3))
    # The bottom edge's middle in the body frame: the edge along x below the centre (y, z < 0).
    a.position = middle - a.rotation @ [0.0, -ha[1], -ha[2]]
    contacts = box_vs_box(1, a, ha, 0, b, hb, margin=5e-3)
    assert len(contacts) == 1
    assert contacts.gap[0] == pytest.approx(height, abs=1e-12)
    np.testing.assert_allclose(contacts.normal[0], [0.0, 0.0, 1.0], atol=1e-12)
    y = middle[1] + (x_b - middle[0]) * np.tan(np.pi / 3)
    np.testing.assert_allclose(contacts.point_a[0], [x_b, y, top_b + height / 2], atol=1e-12)
    np.testing.assert_allclose(contacts.point_b[0], contacts.point_a[0])
    keys = unpack_keys(contacts.ids)
    assert keys["kind"][0] == ContactKind.BOX_BOX and 8 <= keys["feature_a"][0] < 20 and 8 <= keys["feature_b"][0] < 20


def test_a_box_flat_on_a_plane_carries_its_bottom_face_area():
    """A 0.2 x 0.3 x 0.1 m box turned 90 deg about x lies on its 0.2 x 0.1 m face: its four
    bottom corners touch, and their areas sum to that face's 0.02 m^2 (exact up to round-off:
    each is a quarter of 4 h_x h_z)."""
    half = np.array([0.1, 0.15, 0.05])
    box = _box(half, (0.0, 0.0, half[1]), (0, np.pi / 2))
    contacts = box_vs_plane(0, box, half, Plane(), margin=5e-3, static_index=3)
    assert len(contacts) == 4
    np.testing.assert_allclose(contacts.gap, 0.0, atol=1e-15)
    assert contacts.area.sum() == pytest.approx(0.2 * 0.1, rel=1e-12)
    keys = unpack_keys(contacts.ids)
    assert (keys["kind"] == ContactKind.BOX_PLANE).all() and (keys["body_b"] == 3).all()
    assert len(set(keys["feature_a"])) == 4


@pytest.mark.parametrize("offset, turn, overlap", [
    ((0.0, 0.0), 0.0, 0.1 * 0.06),  # centred: the small box's whole footprint
    ((0.18, -0.02), 0.0, (0.2 - 0.13) * 0.06),  # hanging over the big box's x = 0.2 edge
    ((0.0, 0.0), np.pi / 4, None),  # a square turned 45 deg on an equal one: an octagon
], ids=["centred", "overhanging", "octagon"])
def test_box_on_box_areas_sum_to_the_overlap_of_the_faces(offset, turn, overlap):
    """A small box (0.1 x 0.06 x 0.05 m) 0.1 mm above a 0.4 m cube: the contacts' areas sum to
    the overlap of its bottom face with the cube's top, a rectangle [x0, x1] x [y0, y1] of the
    two footprints (exact up to round-off, 1e-12 relative). A 0.4 m square turned 45 deg on an
    equal one overlaps in a regular octagon of area 2 (sqrt 2 - 1) s^2 (the square less four
    corner triangles of legs (2 - sqrt 2) s / 2), touching at its 8 corners, each an edge
    crossing: 8 contacts with distinct keys.
    """
    big_half = np.full(3, 0.2)
    big = RigidBody.box(2 * big_half, DENSITY, position=(0.0, 0.0, 0.2))
    half = big_half if overlap is None else np.array([0.05, 0.03, 0.025])
    small = _box(half, (offset[0], offset[1], 0.4 + half[2] + 1e-4), (2, turn))
    if overlap is None:
        overlap = 2 * (np.sqrt(2) - 1) * 0.4**2
    for contacts in (box_vs_box(1, small, half, 0, big, big_half, margin=5e-3),
                     box_vs_box(0, big, big_half, 1, small, half, margin=5e-3)):
        assert contacts.area.sum() == pytest.approx(overlap, rel=1e-12)
        np.testing.assert_allclose(contacts.gap, 1e-4, atol=1e-12)
        assert len(np.unique(contacts.ids)) == len(contacts) == (8 if turn else 4)


def test_speculative_box_contacts_come_from_the_margin_or_the_approach():
    """A 0.1 m cube 10 mm above another (offset 1 cm sideways): beyond the 5 mm margin no
    contact; falling at 1 m/s over dt = 20 ms it would close 20 mm, so the four corners of the
    faces' overlap rectangle are speculative contacts (gap 10 mm kept as is), whichever box
    moves; the same for its corners against a plane 10 mm below."""
    half = np.full(3, 0.05)
    lower = RigidBody.box(2 * half, DENSITY, position=(0.0, 0.0, 0.05))
    upper = RigidBody.box(2 * half, DENSITY, position=(0.01, 0.0, 0.16))
    falling = np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0])
    assert len(box_vs_box(1, upper, half, 0, lower, half, margin=5e-3)) == 0
    contacts = box_vs_box(1, upper, half, 0, lower, half, margin=5e-3, velocity_a=falling, dt=0.02)
    assert len(contacts) == 4
    np.testing.assert_allclose(contacts.gap, 0.01, atol=1e-12)
    assert len(box_vs_box(0, lower, half, 1, upper, half, margin=5e-3, velocity_b=falling, dt=0.02)) == 4
    assert len(box_vs_plane(1, upper, half, Plane(point=(0.0, 0.0, 0.1)), margin=5e-3)) == 0
    assert len(box_vs_plane(1, upper, half, Plane(point=(0.0, 0.0, 0.1)), margin=5e-3, velocity=falling, dt=0.02)) == 4


def test_a_glued_collision_box_holds_until_the_adhesive_pull_off_force():
    """Adhesion acts on a collision box through its contact areas: a 0.1 m cube (800 kg/m^3)
    on an adhesive plane pulled up by a force ramped at 40 N/s starts to debond at
    F* = m g + A sqrt(W C) (tests/contact/test_adhesion.py), A = 0.01 m^2 its bottom face. It
    must still hold at 0.99 F* (with no area it would lift off at m g, 7.8 N against F* =
    39.5 N) and let go by 1.05 F* (the runaway's few-step overshoot)."""
    from softvr.contact import Adhesion

    adhesion = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)
    cube = RigidBody.box((0.1,) * 3, 800.0, position=(0.0, 0.0, 0.05))
    scene = Scene()
    scene.add_body(cube, collision_box=(0.05,) * 3, adhesion=adhesion)
    scene.add_plane(Plane(friction=0.5), adhesion=adhesion)
    dt, rate = 0.002, 40.0
    for _ in range(20):
        scene.step(dt)
    predicted = cube.mass * G + 0.01 * np.sqrt(1.0 * 1e7)
    held, separated = 0.0, None
    for n in range(1, int(1.1 * predicted / (rate * dt))):
        force = rate * n * dt
        scene.external[0] = np.array([0.0, 0.0, force, 0.0, 0.0, 0.0])
        scene.step(dt)
        beta = list(scene.adhesion_state.intensity.values())
        if beta and min(beta) == 1.0:
            held = force
        if not beta or np.mean(beta) < 0.5:
            separated = force
            break
    assert held >= 0.99 * predicted
    assert separated is not None and separated <= 1.05 * predicted
