"""The detection (the bodies' motion, boxes and creases, the contact gather) and the warm starts'
carry with a thread per point, edge, candidate pair or contact (a GPU's form,
softvr.collision.node_detection's ``parallel``) against the one-thread forms they replace (the
obviously correct reference: a thread walking each body's items; every candidate pair tried in
turn, in the documented order, softvr.collision._node_kernels.gather_contacts).

The truth checked is exact: the same contacts, field for field and bit for bit, in the same
order, and the same carried tables, on scenes that make every kind of contact (points on planes,
static spheres and static meshes, vertices on other bodies' triangles, edge pairs) with warm
starts carried from earlier steps.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.collision.node_detection import record_carry, record_node_detection
from softvr.dynamics import Material
from softvr.scene import bundled, load_scene

from tests.sim.test_node_edge_cover import _turned_cube
from tests.sim.test_node_static_meshes import _sheet
from tests.sim.test_node_static_spheres import _block_on_sphere
from tests.sim.test_node_surfaces import _add_with_surface, _block, _stack

G = 9.81
DT = 1.0 / 60.0
FIELDS = ("kind", "column", "point", "other", "face", "bary", "frame", "gap", "friction", "impulse", "stencil_count",
          "stencil_nodes", "stencil_weights")
TABLES = ("carried", "edge_carried", "edge_partner")
PLANE, VERTEX_TRIANGLE, EDGE_EDGE, SPHERE, MESH = 0, 1, 2, 4, 5


def _on_mesh():
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5)
    _add_with_surface(scene, _block(2, 0.1, (0.0, 0.0, 0.0505), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2)))
    scene.add_mesh(_sheet())
    return scene


def _crossing_edges():
    """Two cubes turned 45 degrees about x and y, the upper one moving down onto the other: their
    edges cross where no vertex touches (test_node_edge_cover.py)."""
    stiff = Material(1e8, 0.3, 500.0, alpha=0.0, beta=1e-3)
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.0, edge_contacts=True)
    half = 0.05
    gap = 2 * half * np.sqrt(2)
    for body in (_turned_cube(half, (1, 0, 0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), stiff),
                 _turned_cube(half, (0, 1, 0), (0.0, 0.0, gap + 0.01), (0.0, 0.0, -0.5), stiff)):
        _add_with_surface(scene, body)
    scene.add_plane(Plane(point=(0.0, 0.0, -1.0)))
    return scene


def _candy():
    return load_scene(bundled("candy.toml"), frames=1, width=64, height=48, haptics=False).scene


#: Scene builder, steps before the comparison, dt [s], and the kinds of contact it must make there
#: (together they cover every kind the gather makes; each with warm starts carried).
SCENES = {"stacked blocks": (lambda: _stack(True)[0], 30, 1.0 / 60.0, {PLANE, VERTEX_TRIANGLE}),
          "block on a sphere": (lambda: _block_on_sphere()[0], 20, 0.01, {SPHERE}),
          "block on a mesh": (_on_mesh, 20, 0.01, {MESH}),
          "crossing edges": (_crossing_edges, 2, 0.01, {EDGE_EDGE}),
          "candy": (_candy, 25, 0.008, {PLANE, VERTEX_TRIANGLE})}


def _gathered(stepper, scene, dt, parallel, tables):
    c = stepper.state.contacts
    for name, value in tables.items():
        getattr(c, name).assign(value)
    record_node_detection(stepper.model, stepper.state, dt, scene.gravity, stepper._surface_margin(), scene.friction,
                          scene.ccd, parallel)()
    n = int(c.count.numpy()[0])
    return n, {name: getattr(c, name).numpy()[:n].copy() for name in FIELDS}, {
        name: getattr(c, name).numpy().copy() for name in TABLES}


@pytest.mark.parametrize("name", SCENES)
def test_the_parallel_detection_makes_the_one_thread_detections_contacts(name):
    build, steps, dt, kinds = SCENES[name]
    scene = build()
    for _ in range(steps):
        scene.step(dt)
    stepper = scene._stepper
    assert type(stepper).__name__ == "NodeStepper"
    c = stepper.state.contacts
    tables = {name: getattr(c, name).numpy().copy() for name in TABLES}
    n, contacts, after = _gathered(stepper, scene, dt, False, tables)
    n_parallel, contacts_parallel, after_parallel = _gathered(stepper, scene, dt, True, tables)
    assert n > 0 and n_parallel == n
    for field in FIELDS:
        np.testing.assert_array_equal(contacts_parallel[field], contacts[field], err_msg=field)
    for table in TABLES:
        np.testing.assert_array_equal(after_parallel[table], after[table], err_msg=table)
    # What the scene's contacts exercise: its kinds, and warm starts read from the carried tables.
    assert set(np.unique(contacts["kind"]).tolist()) >= kinds
    assert np.abs(contacts["impulse"]).max() > 0


def test_the_scenes_cover_every_kind_of_contact_the_gather_makes():
    assert set().union(*(kinds for *_, kinds in SCENES.values())) == {PLANE, VERTEX_TRIANGLE, EDGE_EDGE, SPHERE, MESH}


@pytest.mark.parametrize("name", ["stacked blocks", "candy"])
def test_the_parallel_carry_keeps_the_one_thread_carrys_tables(name):
    """Two carries in a row from the same tables, with random impulses: the first on the step's
    contacts, the second on the first half of them only (so it must clear what the first wrote
    for the others: a pair no longer in contact forgets its impulse)."""
    build, steps, dt, _ = SCENES[name]
    scene = build()
    for _ in range(steps):
        scene.step(dt)
    stepper = scene._stepper
    c = stepper.state.contacts
    n = int(c.count.numpy()[0])
    tables = {name: getattr(c, name).numpy().copy() for name in TABLES}
    rng = np.random.default_rng(1)
    results = []
    for parallel in (False, True):
        for table, value in tables.items():
            getattr(c, table).assign(value)
        carry = record_carry(stepper.model, stepper.state, parallel)
        for count in (n, n // 2):
            c.count.assign([count])
            impulse = c.impulse.numpy()
            impulse[:n] = rng.standard_normal((n, 3))
            c.impulse.assign(impulse)
            carry()
        results.append({table: getattr(c, table).numpy().copy() for table in TABLES})
        rng = np.random.default_rng(1)
    for table in TABLES:
        np.testing.assert_array_equal(results[1][table], results[0][table], err_msg=table)
    kept = np.count_nonzero(np.abs(results[0]["carried"]).sum(axis=2))
    assert 0 < kept <= n // 2  # the second carry's contacts only (edge pairs and primitives are not in it)
