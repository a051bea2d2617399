"""The contacts a step on the node arrays reports (``Scene.last_solution``): each contact's key
names its own bodies and features, unique in the scene, and carries the area it stands for
(thesis 4.3.1), for the rigid bodies' box and sphere primitives too.

Truths: the geometry of bodies resting on a plane. A box resting flat on a plane touches it with
the face turned to it, so its corners' areas sum to that face, ``4 h_x h_y``; a box resting on a
larger box touches it with its whole lower face (the contact polygon); a sphere on a plane
stands for the cap within the contact margin ``h``, ``2 pi R h`` (Archimedes). Areas are sums
and products of a few doubles: relative tolerance 1e-12.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.collision.contacts import ContactKind, unpack_keys
from softvr.dynamics import Coupling, KinematicBody, Material, RigidBody, RigidPoints
from softvr.model.shapes import icosphere
from softvr.sim import node_model_supported

from tests.sim.test_node_rigid import _rigid_box
from tests.sim.test_node_surfaces import _add_with_surface, _block

G = 9.81
GAP = 5e-4  # [m] every body starts this far above what it rests on (within the contact margin)


def _resting_scene():
    """A soft cube (body 0, so that the rigid bodies' scene indices differ from their order
    among the rigid bodies), three box primitives (one resting on another) and two sphere
    primitives on the floor, which is plane 1 (plane 0 a far wall)."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5)
    cube = _block(2, 0.1, (0.6, 0.0, 0.05 + GAP), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2))
    _add_with_surface(scene, cube)
    scene.add_plane(Plane(point=(-5.0, 0.0, 0.0), normal=(1.0, 0.0, 0.0), friction=0.5))
    scene.add_plane(Plane(friction=0.5))
    halves = {"small": np.array([0.05, 0.04, 0.03]), "wide": np.array([0.1, 0.1, 0.02]),
              "top": np.array([0.04, 0.03, 0.02])}
    wide_top = 2 * halves["wide"][2] + GAP
    centres = {"small": (0.0, 0.0, halves["small"][2] + GAP), "wide": (0.3, 0.0, halves["wide"][2] + GAP),
               "top": (0.31, 0.01, wide_top + halves["top"][2] + GAP)}
    index = {}
    for name, half in halves.items():
        _rigid_box(scene, half, 500.0, centres[name], primitive=True, surface=False)
        index[name] = len(scene.bodies) - 1
    radii = {"ball": 0.03, "bead": 0.02}
    for name, (r, xy) in {"ball": (radii["ball"], (0.0, 0.3)), "bead": (radii["bead"], (0.3, 0.3))}.items():
        scene.add_body(RigidBody.sphere(r, 500.0, position=(*xy, r + GAP)), collision_sphere=r)
        index[name] = len(scene.bodies) - 1
    return scene, index, halves, radii


def _primitive_sets(solution):
    """Contact sets of the solution whose side a is a rigid primitive, by (body a, body b or
    None)."""
    out = {}
    for contacts in solution.contacts:
        b = None if contacts.b is None else contacts.b.body
        out.setdefault((contacts.a.body, b), []).append(contacts)
    return out


def test_primitive_contacts_carry_their_bodies_keys_and_the_areas_of_what_touches():
    scene, index, halves, radii = _resting_scene()
    solution = scene.step(0.005)
    assert type(scene._stepper).__name__ == "NodeStepper"
    sets = _primitive_sets(solution)
    floor = 1

    def area(a, b):
        return sum(float(c.area.sum()) for c in sets[(a, b)])

    # A box flat on the floor: its lower face; the top box on the wide one: its own lower face
    # (inside the wide box's upper face, so the whole of it is the contact polygon).
    for name in ("small", "wide"):
        h = halves[name]
        assert area(index[name], None) == pytest.approx(4 * h[0] * h[1], rel=1e-12)
    h = halves["top"]
    pair = (index["top"], index["wide"]) if (index["top"], index["wide"]) in sets else (index["wide"], index["top"])
    assert area(*pair) == pytest.approx(4 * h[0] * h[1], rel=1e-12)
    for name, r in radii.items():
        assert area(index[name], None) == pytest.approx(2 * np.pi * r * scene.contact_margin, rel=1e-12)

    # Every key is the contact's own: its bodies the scene's (side b's a plane index for a
    # plane), its kind what meets, and no two contacts share one.
    keys = np.concatenate([c.ids for c in solution.contacts])
    assert len(np.unique(keys)) == len(keys)
    kinds = {"small": ContactKind.BOX_PLANE, "wide": ContactKind.BOX_PLANE, "ball": ContactKind.SPHERE_PLANE,
             "bead": ContactKind.SPHERE_PLANE}
    for name, kind in kinds.items():
        (contacts,) = sets[(index[name], None)]
        f = unpack_keys(contacts.ids)
        np.testing.assert_array_equal(f["kind"], kind)
        np.testing.assert_array_equal(f["body_a"], index[name])
        np.testing.assert_array_equal(f["body_b"], floor)
    (contacts,) = sets[pair]
    f = unpack_keys(contacts.ids)
    np.testing.assert_array_equal(f["kind"], ContactKind.BOX_BOX)
    np.testing.assert_array_equal(f["body_a"], pair[0])
    np.testing.assert_array_equal(f["body_b"], pair[1])
    # A box's four lower corners on the floor: four distinct corner features.
    (contacts,) = sets[(index["small"], None)]
    assert len(np.unique(unpack_keys(contacts.ids)["feature_a"])) == 4


def _hand_scene(hand_meets_spheres: bool):
    """candy-adhesive.toml's hand in small: a kinematic body with a collision sphere and a
    surface holds a rigid box primitive (with its own surface) by a zero-length spring at the
    box's top centre (thesis eq. 5.4), beside a soft cube, a rigid box and a rigid ball resting
    on the floor. The hand meets nothing (the scene file's ``collides_with = []``) unless
    ``hand_meets_spheres``: then it may meet the ball, sphere to sphere."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5)
    cube = _block(2, 0.1, (0.6, 0.0, 0.05 + GAP), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2))
    _add_with_surface(scene, cube)
    scene.add_plane(Plane(friction=0.5))
    _rigid_box(scene, np.array([0.05, 0.04, 0.03]), 500.0, (0.0, 0.0, 0.03 + GAP), primitive=True)
    scene.add_body(RigidBody.sphere(0.03, 500.0, position=(0.0, 0.3, 0.03 + GAP)), collision_sphere=0.03)
    half = np.array([0.03, 0.02, 0.015])
    held = _rigid_box(scene, half, 500.0, (0.3, 0.0, 0.2), primitive=True)
    grip = np.array([[0.3, 0.0, 0.2 + half[2]]])
    centre = grip[0] + (0.0, 0.0, 0.015)
    hand = KinematicBody(lambda t: (centre, np.array([1.0, 0.0, 0.0, 0.0])), name="hand")
    unit, triangles = icosphere(1)
    scene.add_body(hand, collision_points=RigidPoints(hand, 0.015 * unit), collision_triangles=triangles,
                   collision_sphere=0.015)
    h = len(scene.bodies) - 1
    for other in range(h):
        if not (hand_meets_spheres and other == 2):
            scene.disable_collision(h, other)
    spring = Coupling(RigidPoints.from_world(held, grip), RigidPoints.from_world(hand, grip), SPRING, damping=DAMPING)
    scene.add_coupling(spring)
    return scene, held, spring


SPRING, DAMPING = 20.0, 1.7  # [N/m], [N s/m]: critical for the held box's 36 g (2 sqrt(k m) = 1.70)


def test_a_kinematic_hand_with_a_sphere_holds_a_rigid_box_on_the_arrays_by_hookes_law():
    """A kinematic body with a collision sphere beside rigid primitives steps on the node
    arrays when the filters keep its sphere from theirs, and its spring (eq. 5.4) holds the box
    at rest with the stretch of Hooke's law, k delta = m g. The sweeps stop at a velocity error
    e = 3e-5 m/s (VELOCITY_TOL); at rest that is a force error m e / dt, a stretch error
    m e / (dt k) = 5.4e-6 m; the damped settling (critical, omega = sqrt(k / m) = 23.6 rad/s)
    leaves (1 + omega t) exp(-omega t) ~ 1e-14 of the 17.7 mm stretch after 1.5 s."""
    scene, held, spring = _hand_scene(hand_meets_spheres=False)
    assert node_model_supported(scene)
    dt = 0.01
    for _ in range(150):
        scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper"
    stretch = spring.stretch()[0]
    assert -stretch[2] == pytest.approx(held.mass * G / SPRING, abs=1e-5)
    np.testing.assert_allclose(stretch[:2], 0.0, atol=1e-5)


def test_a_kinematic_sphere_that_may_meet_a_rigid_sphere_keeps_the_per_object_path():
    """Sphere-sphere contacts are the primitives' (the arrays' primitive detection holds the
    rigid bodies alone): a kinematic sphere the filters let meet a rigid one is declined."""
    scene, _, _ = _hand_scene(hand_meets_spheres=True)
    assert not node_model_supported(scene)


def test_resting_bodies_net_contact_force_is_their_weight_read_without_building_the_sets():
    """Statics: a body at rest carries its weight, so the net contact force on it is m g up
    (the wide box: the floor's (m_wide + m_top) g less the top box's m_top g). ``force_on``
    and the haptic tool read the step's bodies, impulses and frames without building the
    sets' Jacobians (``set_bodies``); they must name the pairs the geometry touches.
    Tolerance: the sweeps stop at a velocity change of 1e-5 m/s, an impulse error of at most
    m 1e-5 a contact set, i.e. 1e-5 / (g dt) = 2e-4 of the weight at dt 5 ms; 1e-3 of it."""
    scene, index, halves, radii = _resting_scene()
    dt = 0.005
    for _ in range(60):
        solution = scene.step(dt)
    pairs = set(solution.set_bodies())
    assert {(index[n], None) for n in ("small", "wide", "ball", "bead")} <= pairs
    assert {(index["top"], index["wide"]), (index["wide"], index["top"])} & pairs
    assert (0, None) in pairs  # the soft cube on the floor
    for name in ("small", "wide", "top", "ball", "bead"):
        body = scene.bodies[index[name]]
        np.testing.assert_allclose(solution.force_on(index[name], dt), [0.0, 0.0, body.mass * G],
                                   atol=1e-3 * body.mass * G)
