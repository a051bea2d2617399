"""Whole-scene arrays of FEM bodies on planes: a static :class:`NodeModel` and a mutable
:class:`NodeState`, built from a :class:`~softvr.sim.Scene`'s bodies (the user-facing builder).

Nodes of every body are numbered one after the other (body ``b``'s nodes are
``model.body_node_start[b] : model.body_node_start[b + 1]``), tets and collision points too.
The step matrix ``A`` of thesis eq. 5.2 is kept as 3x3 node blocks in block-CSR order
(``row_start`` / ``block_col``), each block gathering its element entries through
``contrib`` (no atomics).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from softvr.dynamics import EmbeddedPoints, FemBody

__all__ = ["NodeContacts", "NodeModel", "NodeState", "build_node_model", "node_model_supported"]

#: Nodes in a collision point's stencil the arrays hold (4: a point embedded in a tet).
STENCIL = 4


@dataclass
class NodeModel:
    """Everything static of a scene of FEM bodies, as flat arrays (``n`` nodes, ``m`` tets,
    ``nb`` nonzero 3x3 blocks of ``A``, ``p`` collision points, ``s`` planes).

    Attributes
    ----------
    device : str
    node_count, tet_count, block_count, point_count : int
    body_node_start : ndarray of int [bodies + 1]
        First node of each body (host copy).
    body_point_start : ndarray of int [bodies + 1]
        First collision point of each body (host copy).
    rest : wp.array(vec3d) [n] [m]
        Rest positions.
    mass : wp.array(float64) [n] [kg]
        Lumped node masses.
    node_alpha : wp.array(float64) [n] [1/s]
        Mass-proportional Rayleigh damping of the node's body.
    fixed : wp.array(int32) [n]
        1 at Dirichlet nodes (they move at ``NodeState.fixed_velocity``).
    speed_limit : wp.array(float64) [n] [m/s]
        A thousand body sizes per second: faster is a divergence.
    tets : wp.array2d(int32) [m, 4]
        Global node indices.
    dm_inv : wp.array(mat33d) [m] [1/m]
        Inverse rest edge matrices.
    ke : wp.array2d(mat33d) [m, 16] [N/m]
        Linear element stiffness (rest frame) in 3x3 blocks, ``ke[e, 4 a + b]`` coupling the
        tet's nodes a and b.
    tet_beta : wp.array(float64) [m] [s]
        Stiffness-proportional Rayleigh damping of the tet's body.
    corotational : bool
    block_row, block_col : wp.array(int32) [nb]
        Node pair of each block of ``A`` (sorted by row, then column).
    row_start : wp.array(int32) [n + 1]
        Blocks of node ``i``'s row: ``row_start[i] : row_start[i + 1]``.
    contrib_start : wp.array(int32) [nb + 1]; contrib : wp.array(int32) [16 m]
        Block ``k`` sums the element blocks ``contrib[contrib_start[k] : contrib_start[k + 1]]``,
        each coded 16 tet + 4 a + b (rows of node a, columns of node b of the tet).
    force_start : wp.array(int32) [n + 1]; force : wp.array(int32) [4 m]
        Node ``i`` sums the element forces ``force[force_start[i] : force_start[i + 1]]``, coded
        4 tet + a.
    point_nodes : wp.array2d(int32) [p, 4]
        Stencil of each collision point (-1: unused).
    point_weights : wp.array2d(float64) [p, 4]
        Its weights (sum 1).
    point_margin : wp.array(float64) [p] [m]
        Detection margin of the point's body.
    plane_normal : wp.array(vec3d) [s]
        Unit normals.
    plane_offset : wp.array(float64) [s] [m]
        ``n . point`` of each plane.
    plane_friction : wp.array(float64) [s]
        Coulomb coefficient of each plane.
    """

    device: str
    node_count: int
    tet_count: int
    block_count: int
    point_count: int
    body_node_start: np.ndarray
    body_point_start: np.ndarray
    rest: wp.array
    mass: wp.array
    node_alpha: wp.array
    fixed: wp.array
    speed_limit: wp.array
    tets: wp.array
    dm_inv: wp.array
    ke: wp.array
    tet_beta: wp.array
    corotational: bool
    block_row: wp.array
    block_col: wp.array
    row_start: wp.array
    contrib_start: wp.array
    contrib: wp.array
    force_start: wp.array
    force: wp.array
    point_nodes: wp.array
    point_weights: wp.array
    point_margin: wp.array
    plane_normal: wp.array
    plane_offset: wp.array
    plane_friction: wp.array


@dataclass
class NodeContacts:
    """Contacts of collision points with planes, fixed capacity ``c`` (every point against
    every plane); rows ``[:count[0]]`` hold this step's.

    Attributes
    ----------
    capacity : int
    count : wp.array(int32) [1]
    point, plane : wp.array(int32) [c]
        The collision point (global) and the plane of each contact; with the point's body they
        make its key (:func:`softvr.collision.contact_keys`, kind POINT_PLANE).
    frame : wp.array(mat33d) [c]
        Rows: normal, tangent 1, tangent 2 (world).
    gap : wp.array(float64) [c] [m]
        Signed distance at the step's start.
    friction : wp.array(float64) [c]
    impulse : wp.array(vec3d) [c] [N s]
        (normal, tangent 1, tangent 2) impulse; the warm start in, the solution out.
    gap_after : wp.array(float64) [c] [m]
        Linearized gap at the step's end.
    carried : wp.array2d(vec3d) [p, s] [N s]
        World impulse of each (point, plane) pair at the last step: the next warm start.
    """

    capacity: int
    count: wp.array
    point: wp.array
    plane: wp.array
    frame: wp.array
    gap: wp.array
    friction: wp.array
    impulse: wp.array
    gap_after: wp.array
    carried: wp.array


@dataclass
class NodeState:
    """What changes from step to step (``n`` nodes, ``m`` tets, ``nb`` blocks).

    Attributes
    ----------
    q : wp.array(vec3d) [n] [m]
    v : wp.array(vec3d) [n] [m/s]
    fixed_velocity : wp.array(vec3d) [n] [m/s]
        Velocity of the fixed nodes over the next step (Control).
    external : wp.array(vec3d) [n] [N]
        External node forces of the step (``Scene.external``; Control).
    rotations : wp.array(mat33d) [m]; element_forces : wp.array2d(vec3d) [m, 4] [N]
        The element terms at the step's start (R_e; f_e per tet node).
    blocks : wp.array(mat33d) [nb] [kg]; d_inv : wp.array(mat33d) [n] [1/kg]; b : wp.array(vec3d) [n] [kg m/s]
        ``A``, ``D_A^-1`` and ``b`` of eq. 5.2.
    v_hat : wp.array(vec3d) [n] [m/s]
        A sweep's Jacobi update.
    sweep_buffers : list of 3 wp.array(vec3d) [n] [m/s]
        The sweeps' velocities v^k-1, v^k, v^k+1 (rotating).
    diverged : wp.array(int32) [n]
        0, or why the step stopped at the node (``NODE_DIVERGENCE_REASONS``).
    contacts : NodeContacts
    """

    q: wp.array
    v: wp.array
    fixed_velocity: wp.array
    external: wp.array
    rotations: wp.array
    element_forces: wp.array
    blocks: wp.array
    d_inv: wp.array
    b: wp.array
    v_hat: wp.array
    sweep_buffers: list
    diverged: wp.array
    contacts: NodeContacts


def node_model_supported(scene) -> bool:
    """Whether ``scene`` is one :class:`NodeModel` holds: FEM bodies only (all co-rotational or
    all linear), no couplings, static meshes or spheres, no adhesion, at most one set of
    collision points per body (:class:`~softvr.collision.EmbeddedPoints` of that body, stencils
    of at most 4 nodes) and no two collision surfaces that could meet."""
    if scene.couplings or scene.meshes or scene.spheres or not scene.bodies:
        return False
    if not all(type(b) is FemBody for b in scene.bodies) or len({b.corotational for b in scene.bodies}) != 1:
        return False
    if any(a is not None for a in scene._adhesion.values()):
        return False
    owners = [c.body for c in scene._colliders]
    if len(set(owners)) != len(owners):
        return False
    for c in scene._colliders:
        if not isinstance(c.points, EmbeddedPoints) or c.points.body is not scene.bodies[c.body] \
                or c.points.nodes.shape[1] > STENCIL:
            return False
    surfaces = scene._surfaces
    return not any(scene.collision_enabled(a.body_index, b.body_index)
                   for n, a in enumerate(surfaces) for b in surfaces[n + 1:])


def _i32(values, device):
    return wp.array(np.ascontiguousarray(values, np.int32), dtype=wp.int32, device=device)


def _f64(values, device, dtype=wp.float64):
    return wp.array(np.ascontiguousarray(values, np.float64), dtype=dtype, device=device)


def _pattern(tets: np.ndarray, n: int) -> tuple:
    """Block-CSR pattern of ``A`` and the gather lists of its blocks and of the node forces."""
    m = len(tets)
    e, a, b = np.meshgrid(np.arange(m), np.arange(4), np.arange(4), indexing="ij")
    rows, cols = tets[e, a].ravel(), tets[e, b].ravel()
    keys, block = np.unique(rows.astype(np.int64) * n + cols, return_inverse=True)
    order = np.argsort(block, kind="stable")
    contrib = (16 * e + 4 * a + b).ravel()[order]
    contrib_start = np.searchsorted(block[order], np.arange(len(keys) + 1))
    block_row, block_col = keys // n, keys % n
    row_start = np.searchsorted(block_row, np.arange(n + 1))
    nodes = tets.ravel()
    by_node = np.argsort(nodes, kind="stable")
    force = (4 * np.arange(m)[:, None] + np.arange(4)).ravel()[by_node]
    force_start = np.searchsorted(nodes[by_node], np.arange(n + 1))
    return block_row, block_col, row_start, contrib_start, contrib, force_start, force


def build_node_model(scene, device: str = "cpu") -> tuple[NodeModel, NodeState]:
    """The arrays of a scene :func:`node_model_supported` accepts, at its bodies' current state."""
    bodies = scene.bodies
    node_start = np.cumsum([0] + [len(b.q) for b in bodies])
    n = int(node_start[-1])
    tets = np.concatenate([b.tets + s for b, s in zip(bodies, node_start)]).astype(np.int64)
    m = len(tets)
    block_row, block_col, row_start, contrib_start, contrib, force_start, force = _pattern(tets, n)

    def per_node(values):
        return np.concatenate([np.full(len(b.q), v) for b, v in zip(bodies, values)])

    scale = [1e3 * max(float(np.ptp(b.rest, axis=0).max()), 1e-9) for b in bodies]
    colliders = {c.body: c for c in scene._colliders}
    point_start = np.cumsum([0] + [len(colliders[i].points.nodes) if i in colliders else 0
                                   for i in range(len(bodies))])
    p = int(point_start[-1])
    point_nodes = np.full((p, STENCIL), -1, np.int64)
    point_weights = np.zeros((p, STENCIL))
    point_margin = np.zeros(p)
    for i, c in colliders.items():
        rows = slice(point_start[i], point_start[i + 1])
        k = c.points.nodes.shape[1]
        point_nodes[rows, :k] = c.points.nodes + node_start[i]
        point_weights[rows, :k] = c.points.weights
        point_margin[rows] = c.margin
    planes = scene.planes
    normals = np.array([pl.unit_normal() for pl in planes], float).reshape(-1, 3)
    offsets = np.array([float(np.asarray(pl.point, float) @ nrm) for pl, nrm in zip(planes, normals)])
    d = device
    model = NodeModel(
        device=d, node_count=n, tet_count=m, block_count=len(block_row), point_count=p,
        body_node_start=node_start, body_point_start=point_start,
        rest=_f64(np.concatenate([b.rest for b in bodies]), d, wp.vec3d),
        mass=_f64(np.concatenate([b.mass for b in bodies]), d),
        node_alpha=_f64(per_node([b.material.alpha for b in bodies]), d),
        fixed=_i32(np.concatenate([b.fixed for b in bodies]), d),
        speed_limit=_f64(per_node(scale), d),
        tets=_i32(tets, d), dm_inv=_f64(np.concatenate([b._dm_inv for b in bodies]), d, wp.mat33d),
        ke=_f64(np.concatenate([b._ke for b in bodies]).reshape(m, 4, 3, 4, 3).transpose(0, 1, 3, 2, 4)
                .reshape(m, 16, 3, 3), d, wp.mat33d),
        tet_beta=_f64(np.concatenate([np.full(len(b.tets), b.material.beta) for b in bodies]), d),
        corotational=bool(bodies[0].corotational),
        block_row=_i32(block_row, d), block_col=_i32(block_col, d), row_start=_i32(row_start, d),
        contrib_start=_i32(contrib_start, d), contrib=_i32(contrib, d),
        force_start=_i32(force_start, d), force=_i32(force, d),
        point_nodes=_i32(point_nodes, d), point_weights=_f64(point_weights, d), point_margin=_f64(point_margin, d),
        plane_normal=_f64(normals, d, wp.vec3d), plane_offset=_f64(offsets, d),
        plane_friction=_f64([pl.friction for pl in planes], d))
    capacity = max(p * len(planes), 1)
    contacts = NodeContacts(
        capacity=capacity, count=wp.zeros(1, dtype=wp.int32, device=d),
        point=wp.zeros(capacity, dtype=wp.int32, device=d), plane=wp.zeros(capacity, dtype=wp.int32, device=d),
        frame=wp.zeros(capacity, dtype=wp.mat33d, device=d), gap=wp.zeros(capacity, dtype=wp.float64, device=d),
        friction=wp.zeros(capacity, dtype=wp.float64, device=d),
        impulse=wp.zeros(capacity, dtype=wp.vec3d, device=d), gap_after=wp.zeros(capacity, dtype=wp.float64, device=d),
        carried=wp.zeros((max(p, 1), max(len(planes), 1)), dtype=wp.vec3d, device=d))

    def vec():
        return wp.zeros(n, dtype=wp.vec3d, device=d)

    state = NodeState(
        q=_f64(np.concatenate([b.q for b in bodies]), d, wp.vec3d),
        v=_f64(np.concatenate([b.v for b in bodies]), d, wp.vec3d),
        fixed_velocity=_f64(np.concatenate([b.fixed_velocity for b in bodies]), d, wp.vec3d),
        external=vec(), rotations=wp.zeros(m, dtype=wp.mat33d, device=d),
        element_forces=wp.zeros((m, 4), dtype=wp.vec3d, device=d),
        blocks=wp.zeros(len(block_row), dtype=wp.mat33d, device=d), d_inv=wp.zeros(n, dtype=wp.mat33d, device=d),
        b=vec(), v_hat=vec(), sweep_buffers=[vec(), vec(), vec()], diverged=wp.zeros(n, dtype=wp.int32, device=d),
        contacts=contacts)
    return model, state
