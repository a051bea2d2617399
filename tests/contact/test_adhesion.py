"""Implicit adhesion (thesis ch. 4) against the model's own analytic consequences.

Pull-off force. At intensity beta = 1 the interface holds a traction p with a gap
g = p / C (eq. 4.10, p = C beta^2 g); its debonding term C g^2 beta (eq. 4.12) reaches the
maximum energy W at p* = sqrt(W C). A rigid cube resting on an adhesive plane and pulled up by
a slowly ramped force F therefore starts to debond when the traction over its contacts,
(F - m g) / sum(A_i), reaches p*: F* = m g + sum(A_i) sqrt(W C). With a small viscosity eta
debonding then runs away within a few steps (the energy p^2 / (C beta^3) grows as beta
drops), so the cube separates at F* within the ramp's few-step overshoot: the test allows
5 % above F* and nothing below. Pulled sideways (no friction) it lets go at
F_t* = sum(A_i) sqrt(W C), the tangential traction alone debonding under compression (4.3.3).

Contact areas (4.3.1, projected onto the contact plane: tests/contact/test_contact_area.py):
the cube's closed surface is q x q quads per face, and each bottom vertex carries a third of
its bottom triangles; the side triangles at the rim stand perpendicular to the plane and count
nothing, so sum(A_i) is the face's area L^2 at any q.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.collision.contacts import unpack_keys
from softvr.contact import Adhesion, combine
from softvr.dynamics import RigidBody, RigidPoints
from softvr.errors import InputError
from softvr.model.shapes import box_surface

EDGE, QUADS, DENSITY, G = 0.1, 4, 800.0, 9.81


def adhesive_cube(adhesion, *, friction=0.5, dt=0.002, quads=QUADS):
    verts, tris = box_surface((EDGE,) * 3, quads)
    cube = RigidBody.box((EDGE,) * 3, DENSITY, position=(0.0, 0.0, EDGE / 2), name="cube")
    scene = Scene(contact_margin=0.002)
    scene.add_body(cube, collision_points=RigidPoints(cube, verts - EDGE / 2), collision_triangles=tris,
                   adhesion=adhesion)
    scene.add_plane(Plane(friction=friction), adhesion=adhesion)
    for _ in range(20):  # settle
        scene.step(dt)
    return scene, cube


def mean_beta(scene):
    values = list(scene.adhesion_state.intensity.values())
    return float(np.mean(values)) if values else 0.0


def ramp_until_debonded(scene, cube, direction, rate, dt, limit):
    """Ramp a force along ``direction`` at ``rate`` [N/s], applied at the centre of the bottom
    face (so that a sideways pull shears the interface without tipping the cube); return the
    force when the mean intensity first falls below 1/2 (the runaway), and the largest force
    with beta still 1."""
    holding = 0.0
    lever = np.array([0.0, 0.0, -EDGE / 2])  # bottom-face centre from the centre of mass
    for n in range(1, int(limit / (rate * dt))):
        force = rate * n * dt * np.asarray(direction, float)
        scene.external[0] = np.concatenate([force, np.cross(lever, force)])
        force = float(np.linalg.norm(force))
        scene.step(dt)
        beta = mean_beta(scene)
        if beta == 1.0:
            holding = force
        if beta < 0.5:
            return force, holding
    raise AssertionError("never debonded")


def contact_area_sum():
    return EDGE**2  # the bottom face's, shared among its vertices (module docstring)


def contact_area_as_detected(contacts, quads=QUADS):
    """Summed area [m^2] of the closed cube's bottom contacts from the geometry, at the pose they
    were detected in (the rotation R from three bottom corners among the contact points): the
    bottom face projected onto the plane, L^2 R_zz, plus, of the side faces tilted towards it,
    the thirds at the rim vertices of their bottom row's triangles (three per quad of h^2 / 2,
    L^2 / (2 q) per face) projected likewise. At rest the cube tilts by ~1e-8 rad, so this is
    L^2 (contact_area_sum) within 1e-8."""
    verts, _ = box_surface((EDGE,) * 3, quads)
    at = dict(zip(unpack_keys(contacts.ids)["feature_a"].tolist(), contacts.point_a))
    corner = [at[int(np.flatnonzero(np.all(np.isclose(verts, c), axis=1))[0])]
              for c in ((0, 0, 0), (EDGE, 0, 0), (0, EDGE, 0))]
    x, y = (corner[1] - corner[0]) / EDGE, (corner[2] - corner[0]) / EDGE
    z = np.cross(x, y)
    return EDGE**2 * (z[2] + (abs(x[2]) + abs(y[2])) / (2 * quads))


def test_normal_pull_off_force_is_m_g_plus_area_times_sqrt_w_c():
    adhesion = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)
    scene, cube = adhesive_cube(adhesion)
    assert len(scene.last_solution.contacts[0]) == (QUADS + 1) ** 2
    contacts = scene.last_solution.contacts[0]
    np.testing.assert_allclose(contacts.area.sum(), contact_area_as_detected(contacts), rtol=1e-9)
    predicted = cube.mass * G + contact_area_sum() * np.sqrt(1.0 * 1e7)
    separated, held = ramp_until_debonded(scene, cube, (0, 0, 1), rate=40.0, dt=0.002, limit=2 * predicted)
    assert predicted <= separated <= 1.05 * predicted
    assert held >= 0.99 * predicted  # no debonding below F*
    # Then it comes off: pulled on, the cube leaves the plane and the contacts are forgotten.
    for _ in range(100):
        scene.step(0.002)
    assert cube.position[2] > EDGE / 2 + adhesion.debond_gap and not scene.adhesion_state.intensity


def test_tangential_pull_off_force_is_area_times_sqrt_w_c():
    adhesion = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)
    scene, cube = adhesive_cube(adhesion, friction=0.0)
    predicted = contact_area_sum() * np.sqrt(1.0 * 1e7)
    separated, held = ramp_until_debonded(scene, cube, (1, 0, 0), rate=40.0, dt=0.002, limit=2 * predicted)
    assert predicted <= separated <= 1.05 * predicted
    assert held >= 0.99 * predicted


def test_larger_viscosity_debonds_more_slowly():
    forces = []
    for eta in (1e-3, 3e-2):
        scene, cube = adhesive_cube(Adhesion(stiffness=1e7, max_energy=1.0, viscosity=eta))
        forces.append(ramp_until_debonded(scene, cube, (0, 0, 1), rate=40.0, dt=0.002, limit=200.0)[0])
    assert forces[1] > 1.02 * forces[0]  # the ramp got further before the runaway


def test_bonding_saturates_at_the_compression_over_p0():
    """A regular tetrahedron standing on a face carries its weight on three contacts equally
    (statically determinate, unlike the cube's 25), each with compression c = m g / (3 A),
    A = a third of the face area: each corner's share of the bottom face (its three side faces
    turn away from the plane and count nothing), so c = m g / (face area), the weight's pressure.
    Initially unbonded, it bonds at beta_dot = r (c - beta p0) (eq. 4.11): beta rises to c / p0
    and stays there."""
    side = 0.1
    corners = np.array([[0.0, 0.0, 0.0], [side, 0.0, 0.0], [side / 2, side * np.sqrt(3) / 2, 0.0],
                        [side / 2, side * np.sqrt(3) / 6, side * np.sqrt(2.0 / 3.0)]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]])
    centre = corners.mean(axis=0)
    body = RigidBody.sphere(0.03, 1000.0, position=centre, name="tetrahedron")
    area = np.sqrt(3) / 4 * side**2 / 3
    c = body.mass * G / (3 * area)
    p0 = 2.0 * c
    adhesion = Adhesion(stiffness=1e7, max_energy=1e3, viscosity=1.0, bonding_rate=5.0 / c, saturation=p0,
                        initial=0.0)
    scene = Scene(contact_margin=0.002)
    scene.add_body(body, collision_points=RigidPoints(body, corners - centre), collision_triangles=faces,
                   adhesion=adhesion)
    scene.add_plane(Plane(friction=0.5), adhesion=adhesion)
    history = []
    for _ in range(400):
        scene.step(0.002)
        history.append(sorted(scene.adhesion_state.intensity.values()))
    history = np.array(history)
    assert history.shape == (400, 3)
    np.testing.assert_allclose(scene.last_solution.contacts[0].area, area, rtol=1e-9)
    assert history.min() >= 0.0 and history.max() <= c / p0 * (1 + 1e-3)
    np.testing.assert_allclose(history[-1], c / p0, rtol=0.01)
    # beta_dot = r c (1 - beta / (c / p0)): after t, beta = (c / p0)(1 - exp(-r p0 t)).
    t = 0.002 * np.arange(1, 401)
    expected = c / p0 * (1 - np.exp(-(5.0 / c) * p0 * t))
    np.testing.assert_allclose(history.mean(axis=1), expected, atol=0.02 * c / p0)


def test_adhesion_off_gives_exactly_plain_contact():
    plain, cube_a = adhesive_cube(None)
    off, cube_b = adhesive_cube(Adhesion(stiffness=0.0, max_energy=1.0, viscosity=1.0))
    for scene in (plain, off):
        scene.external[0] = np.array([3.0, 1.0, 2.0, 0.0, 0.0, 0.01])
        for _ in range(50):
            scene.step(0.002)
    np.testing.assert_array_equal(cube_a.position, cube_b.position)
    np.testing.assert_array_equal(cube_a.v, cube_b.v)


@pytest.mark.parametrize("field, value, match", [
    ("stiffness", -1.0, "Adhesion.stiffness"), ("initial", 1.5, "Adhesion.initial"),
    ("initial", -0.1, "Adhesion.initial"), ("viscosity", 0.0, "Adhesion.viscosity"),
])
def test_bad_parameters_are_clear_errors(field, value, match):
    args = {"stiffness": 1e7, "max_energy": 1.0, "viscosity": 1.0} | {field: value}
    with pytest.raises(InputError, match=match):
        Adhesion(**args)


def test_combining_materials():
    jello = Adhesion(stiffness=4e7, max_energy=2.0, viscosity=0.1, initial=0.8)
    candy = Adhesion(stiffness=1e6, max_energy=0.5, viscosity=0.4, initial=1.0)
    both = combine(jello, candy)
    assert both.stiffness == pytest.approx(np.sqrt(4e7 * 1e6)) and both.max_energy == pytest.approx(1.0)
    assert both.viscosity == pytest.approx(0.2) and both.initial == 0.8
    assert combine(jello, None) is None and combine(None, candy) is None


@pytest.mark.parametrize("stiffness", [1e6, 1e7, 1e8])
@pytest.mark.parametrize("dt", [0.001, 0.002, 0.005])
def test_stable_over_the_thesis_range_of_stiffness_and_time_step(stiffness, dt):
    """Thesis 4.4: stable for C in 1e6..1e8 N/m^3 at dt 1-5 ms. A soft FEM cube lands on an
    adhesive plane, sticks, then a ramped pull tears it off. The system only dissipates, so
    its kinetic energy can never exceed what went in: the gravitational energy released plus
    the work of the pull (elastic and adhesive energies are >= 0)."""
    from softvr.dynamics import EmbeddedPoints, FemBody, Material
    from softvr.volume import Volume, boundary_faces, grid_tet_mesh

    h = 0.05
    nodes, tets = grid_tet_mesh(Volume(np.zeros((2, 2, 2), np.uint8), spacing=(h,) * 3, origin=(h / 2, h / 2,
                                                                                                   0.01 + h / 2)), 2)
    body = FemBody(nodes, tets, Material(1e5, 0.3, 1000.0, alpha=1.0, beta=1e-3), name="jelly")
    faces = boundary_faces(tets)
    adhesion = Adhesion(stiffness=stiffness, max_energy=0.5, viscosity=0.05)
    scene = Scene(contact_margin=0.002)
    scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(nodes))[:, None],
                                                         np.ones((len(nodes), 1))),
                   collision_triangles=faces, adhesion=adhesion)
    scene.add_plane(Plane(friction=0.5), adhesion=adhesion)
    mass = body.mass.sum()
    work = 0.0
    com0 = body.q[:, 2] @ body.mass / mass
    stuck = False
    for n in range(int(0.6 / dt)):
        t = n * dt
        force = max(t - 0.2, 0.0) * 400.0  # [N], after 0.2 s of rest
        scene.external[0] = np.tile([0.0, 0.0, force / len(nodes)], (len(nodes), 1))
        z0 = body.q[:, 2].mean()
        scene.step(dt)
        work += force * (body.q[:, 2].mean() - z0)
        energy_in = mass * G * (com0 - body.q[:, 2] @ body.mass / mass) + work
        stuck |= any(lam[:, 0].min() < 0 for lam in scene.last_solution.impulses)  # adhesion pulled
        assert np.isfinite(body.q).all() and body.kinetic_energy() <= energy_in * (1 + 1e-6) + 1e-9
    assert stuck


def time_to_full_debond(quads: int, dt: float = 0.004) -> float:
    """A 0.4 m cloth (1 kg/m^2) pinned at its top edge lies against an adhesive wall that
    overhangs by 20 degrees, pressed on at 2 cm/s; gravity pulls it off with a normal traction
    of rho g sin 20 = 3.4 Pa and drags it down the wall with rho g cos 20 = 9.2 Pa, both above
    the debonding onset sqrt(W C) = 2.0 Pa (the bonds' tangential stretch, held under traction,
    tears them, eq. 4.12). Returns the time [s] at which the last vertex lets go (about 1.1 s)."""
    from softvr.dynamics import ClothBody, EmbeddedPoints

    size, top, tilt = 0.4, 1.0, np.radians(20.0)
    normal = np.array([np.cos(tilt), 0.0, -np.sin(tilt)])
    down = np.array([-np.sin(tilt), 0.0, -np.cos(tilt)])  # down the wall
    origin = np.array([0.0, -size / 2, top]) + size * down
    cloth = ClothBody.grid(size, size, quads, quads, origin=origin, u_axis=(0.0, 1.0, 0.0), v_axis=-down,
                           density=1.0, stretch=300.0, shear=30.0, alpha=0.2, name=f"cloth {quads}")
    cloth.fixed[:] = (cloth.q - origin) @ -down > size - 1e-9
    cloth.v[:] = -0.02 * normal
    n = len(cloth.q)
    adhesion = Adhesion(stiffness=1e6, max_energy=4e-6, viscosity=3e-4, debond_gap=0.004)
    scene = Scene(friction=0.3, contact_margin=0.002)
    scene.add_body(cloth, collision_points=EmbeddedPoints(cloth, np.arange(n)[:, None], np.ones((n, 1))),
                   collision_triangles=cloth.triangles, adhesion=adhesion)
    scene.add_plane(Plane(point=(0.0, 0.0, top), normal=tuple(normal), friction=0.3), adhesion=adhesion)
    bonded = []
    for step in range(int(3.0 / dt)):
        scene.step(dt)
        bonded.append(sum(1 for beta in scene.adhesion_state.intensity.values() if beta > 0))
        if bonded[-1] == 0 and max(bonded) > 0:
            assert max(bonded) > (quads + 1) * quads * 0.9  # it had bonded all along the wall
            return (step + 1) * dt
    raise AssertionError(f"still {bonded[-1]} vertices bonded after 3 s")


def test_cloth_on_a_wall_debonds_in_the_same_time_at_three_resolutions():
    """Thesis 4.4: adhesion's behaviour varies little with mesh resolution. Tractions are
    impulses per local area (4.3.1), so the debonding law sees the same traction at any
    resolution: the times to full debond agree within 15 %."""
    times = [time_to_full_debond(quads) for quads in (8, 12, 16)]
    assert max(times) <= 1.15 * min(times), times


@pytest.mark.parametrize("friction", [0.0, 0.5])
def test_bonded_block_holds_a_sideways_force_like_a_spring(friction):
    """A bonded contact holds tangentially like a spring (eq. 4.10 along the tangent plane,
    :mod:`softvr.contact.adhesion`): every bonded contact i pulls back with A_i C beta^2 times
    its slip since bonding. The cube translates rigidly (the force acts at the bottom-face
    centre, in the plane of the springs, so nothing tips), so a sideways F below the tangential
    limit sum(A_i) sqrt(W C) (47 N here) stretches all of them by the same u = F / sum(A_i C)
    (beta = 1): 63 um for 9.5 N, reached within a few oscillations of period
    2 pi sqrt(m / sum(A_i C)) = 15 ms and then held. Without friction nothing else holds it;
    with friction the larger of the two bounds holds (4.3.2), so at most u. Tolerance: the PGS
    stops at 1e-5 m/s of velocity residual, a slip error of 2e-8 m per step that the spring
    takes back within a few steps: well under 1 % of u."""
    adhesion = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)
    scene, cube = adhesive_cube(adhesion, friction=friction)
    stiffness = adhesion.stiffness * sum(c.area.sum() for c in scene.last_solution.contacts)  # [N/m]
    force = np.array([9.5, 0.0, 0.0])
    assert np.linalg.norm(force) < 0.5 * sum(c.area.sum() for c in scene.last_solution.contacts) * np.sqrt(1e7)
    scene.external[0] = np.concatenate([force, np.cross([0.0, 0.0, -EDGE / 2], force)])
    x0 = cube.position[0]
    shift = []
    for _ in range(1000):  # 2 s
        scene.step(0.002)
        shift.append(cube.position[0] - x0)
    shift = np.array(shift)
    spring = force[0] / stiffness
    assert np.abs(shift).max() < 1e-3 and mean_beta(scene) == 1.0  # held, still bonded
    assert abs(shift[-1] - shift[499]) < 0.01 * spring  # no creep over the last second
    if friction == 0.0:
        np.testing.assert_allclose(shift[500:], spring, rtol=0.01)
    else:
        assert np.all(shift[500:] <= 1.01 * spring)


def bottom_face_block(quads, adhesion):
    """The adhesive cube whose collision surface is its bottom face, q x q quads: the face
    that touches the plane, meshed at any resolution, with a true area of EDGE^2."""
    verts, tris = box_surface((EDGE,) * 3, quads)
    tris = tris[(verts[tris][:, :, 2] < 1e-9).all(axis=1)]
    cube = RigidBody.box((EDGE,) * 3, DENSITY, position=(0.0, 0.0, EDGE / 2), name="cube")
    scene = Scene(contact_margin=0.002)
    scene.add_body(cube, collision_points=RigidPoints(cube, verts - EDGE / 2), collision_triangles=tris,
                   adhesion=adhesion)
    scene.add_plane(Plane(friction=0.5), adhesion=adhesion)
    for _ in range(20):  # settle
        scene.step(0.002)
    return scene, cube


@pytest.mark.parametrize("quads", [1, 4, 10])
def test_pull_off_force_does_not_depend_on_the_mesh(quads):
    """The pull-off force of the module docstring, F* = m g + A sqrt(W C), with A the face's
    true area (100 cm^2), at 1 x 1, 4 x 4 and 10 x 10 quads: vertex areas are each vertex's
    share of the surface (a third of every triangle at it) and so sum to the face's area at
    any resolution. The thesis' mean of the incident triangles' areas gave 200, 78 and 60.5
    cm^2. Bounds as in the normal pull-off test: nothing below F*, 5 % above (well within
    15 %)."""
    adhesion = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)
    scene, cube = bottom_face_block(quads, adhesion)
    assert len(scene.last_solution.contacts[0]) == (quads + 1) ** 2
    predicted = cube.mass * G + EDGE**2 * adhesion.traction_limit()
    separated, held = ramp_until_debonded(scene, cube, (0, 0, 1), rate=40.0, dt=0.002, limit=2 * predicted)
    assert predicted <= separated <= 1.05 * predicted
    assert held >= 0.99 * predicted


@pytest.mark.parametrize("quads", [1, 4, 10])
def test_closed_cube_pull_off_force_does_not_depend_on_the_mesh(quads):
    """A closed cube (all six faces, q x q quads each) comes off at F* = m g + L^2 sqrt(W C) at
    q = 1, 4 and 10: its bottom vertices carry the bottom face's area projected onto the plane,
    and nothing of the side faces at the rim, which stand perpendicular to it. Counting the
    side triangles' thirds there (every incident triangle's area, unprojected) made it
    L^2 (1 + 2 / q): pull-off at 85.8, 53.8 and 45.9 N against F* = 39.5 N. Bounds as in the
    normal pull-off test: nothing below F*, 5 % above (well within 15 %)."""
    adhesion = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)
    scene, cube = adhesive_cube(adhesion, quads=quads)
    assert len(scene.last_solution.contacts[0]) == (quads + 1) ** 2
    predicted = cube.mass * G + EDGE**2 * adhesion.traction_limit()
    separated, held = ramp_until_debonded(scene, cube, (0, 0, 1), rate=40.0, dt=0.002, limit=2 * predicted)
    assert predicted <= separated <= 1.05 * predicted
    assert held >= 0.99 * predicted


def test_contacts_without_area_do_not_adhere():
    """Collision points without a surface stand for no area (0): with adhesion on both sides
    they neither bond nor produce tractions (no division by 0), and a cube resting on them
    lifts off at its weight, as without adhesion."""
    adhesion = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)
    cube = RigidBody.box((EDGE,) * 3, DENSITY, position=(0.0, 0.0, EDGE / 2), name="cube")
    scene = Scene(contact_margin=0.002)
    corners = np.array([[x, y, -EDGE / 2] for x in (-EDGE / 2, EDGE / 2) for y in (-EDGE / 2, EDGE / 2)])
    scene.add_body(cube, collision_points=RigidPoints(cube, corners), adhesion=adhesion)
    scene.add_plane(Plane(friction=0.5), adhesion=adhesion)
    with np.errstate(all="raise"):  # an infinite traction or energy would raise here
        for _ in range(20):
            scene.step(0.002)
        assert len(scene.last_solution.contacts[0]) == 4 and not scene.adhesion_state.intensity
        scene.external[0] = np.array([0.0, 0.0, 1.05 * cube.mass * G, 0.0, 0.0, 0.0])
        for _ in range(50):
            scene.step(0.002)
    assert cube.position[2] > EDGE / 2 + 1e-3 and np.isfinite(cube.position).all()
