"""Whole-scene arrays of FEM and cloth bodies, the kinematic and fixed bodies they meet, and static planes:
a static :class:`NodeModel` and a mutable :class:`NodeState`, built from a
:class:`~softvr.sim.Scene`'s bodies (the user-facing builder).

Nodes of every body are numbered one after the other (body ``b``'s nodes are
``model.body_node_start[b] : model.body_node_start[b + 1]``), tets and collision points too.
A kinematic or fixed body's collision points are driven nodes of their own (no tets, moving at
the body's scripted velocity), so that every contact, whoever it is with, is a stencil of node
velocities. The step matrix ``A`` of thesis eq. 5.2 is kept as 3x3 node blocks in block-CSR
order (``row_start`` / ``block_col``), each block gathering its element entries through
``contrib`` (no atomics); a cloth's vertices are free nodes too, its springs blocks of ``A``
(:mod:`softvr.sim._node_cloth`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from softvr.collision.edges import PAIRS_PER_EDGE
from softvr.collision.node_detection import CONTACT_STENCIL
from softvr.dynamics import ClothBody, EmbeddedPoints, FemBody, FixedBody, KinematicBody, RigidBody, RigidPoints
from softvr.sim._node_cloth import NODE_BODIES, NodeCloth, build_node_cloth, cloth_block_keys, cloth_springs
from softvr.sim._node_couplings import (NodeCouplings, build_node_couplings, coupling_blocks, coupling_springs,
                                       couplings_supported, driven_points)
from softvr.sim._node_rigid import NodeRigid, build_node_rigid

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
    assembled : wp.array(int32) [na]
        The blocks the assembly sums: one of each transposed pair (``A`` is symmetric: the
        other is written as its transpose) and every block without one.
    block_mirror : wp.array(int32) [nb]
        The block at the transposed position (column, row) (itself on the diagonal; -1: none,
        a coupling's block from a driven node).
    force_start : wp.array(int32) [n + 1]; force : wp.array(int32) [4 m]
        Node ``i`` sums the element forces ``force[force_start[i] : force_start[i + 1]]``, coded
        4 tet + a.
    point_nodes : wp.array2d(int32) [p, 4]
        Stencil of each collision point (-1: unused).
    point_weights : wp.array2d(float64) [p, 4]
        Its weights (sum 1).
    point_margin : wp.array(float64) [p] [m]
        Detection margin of the point's body.
    plane_margin : wp.array(float64) [p] [m]
        The point's margin against planes: -inf for a rigid body's point with a primitive (the
        primitive meets the planes exactly), else ``point_margin``.
    plane_normal : wp.array(vec3d) [s]
        Unit normals.
    plane_offset : wp.array(float64) [s] [m]
        ``n . point`` of each plane.
    plane_friction : wp.array(float64) [s]
        Coulomb coefficient of each plane.
    sphere_center : wp.array(vec3d) [k] [m]; sphere_radius : wp.array(float64) [k] [m];
    sphere_friction : wp.array(float64) [k]
        The static spheres (``Scene.spheres``).
    static_meshes : list of wp.Mesh; static_mesh_ids : wp.array(uint64) [ms]
        The static triangle meshes' (``Scene.meshes``) BVHs on the arrays' device.
    static_mesh_thickness : wp.array(float32) [ms] [m]; static_mesh_friction : wp.array(float64) [ms]
        Their half thicknesses and Coulomb coefficients.
    point_body : wp.array(int32) [p]
        Body of each collision point.
    body_point_start_wp : wp.array(int32) [bodies + 1]
        ``body_point_start`` on the device.
    triangles : wp.array2d(int32) [t, 3]
        Every collision surface's triangles over global collision points (body ``b``'s are
        ``body_triangle_start[b] : body_triangle_start[b + 1]``).
    body_triangle_start : wp.array(int32) [bodies + 1]
    surfaces : dict
        Body index -> its :class:`~softvr.collision.CollisionSurface` (host).
    meshes : list of wp.Mesh
        The surfaces' BVHs over ``NodeState.point_x32`` (views of each body's points), refitted
        every step.
    mesh_ids : wp.array(uint64) [bodies]
        Each body's mesh (0: no surface).
    pair_enabled : wp.array2d(int32) [bodies, bodies]
        1 where body a's surface vertices meet body b's triangles.
    kinematic : list of int
        Kinematic and fixed bodies (host): their collision points are driven nodes.
    drive_node, drive_body : wp.array(int32) [nd]; drive_local : wp.array(vec3d) [nd] [m]
        Each driven node, its body's row in ``kinematic`` and its point in that body's frame
        (relative to the centre of mass).
    edges : wp.array2d(int32) [e, 2]
        The surfaces' edges over global collision points (none when ``Scene.edge_contacts`` is
        off or no two surfaces meet); body ``b``'s are ``body_edge_start[b] : [b + 1]``.
    edge_faces : wp.array2d(int32) [e, 2]
        Their one or two triangles (global; -1: an open border).
    edge_body : wp.array(int32) [e]
    body_edge_start : wp.array(int32) [bodies + 1]
    bvhs : list of wp.Bvh
        Each surface's BVH over its edges' boxes (``NodeState.edge_lower`` / ``edge_upper``).
    bvh_ids : wp.array(uint64) [bodies]
    crease_bvhs : list of wp.Bvh; crease_bvh_ids : wp.array(uint64) [bodies]
        Their twins over the crease and border edges' boxes only (``NodeState.crease_lower`` /
        ``crease_upper``), built from the same boxes so that a query visits the crease edges in
        the order the full BVH's does (the smooth edges' queries, which need a crease on the other side).
    couplings : NodeCouplings
        The coupling springs (thesis eq. 5.4): their blocks of ``A``, forces and the kinematic
        and fixed bodies' driven nodes (collision points, then coupling points).
    rigid : NodeRigid or None
        The rigid bodies (each two nodes: linear and angular velocity), their primitives and
        collision points' body frame (None: no rigid body).
    cloth : NodeCloth
        The cloth bodies' springs: their blocks of ``A`` and forces (none without cloth).
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
    assembled: wp.array
    block_mirror: wp.array
    force_start: wp.array
    force: wp.array
    point_nodes: wp.array
    point_weights: wp.array
    point_margin: wp.array
    plane_margin: wp.array
    plane_normal: wp.array
    plane_offset: wp.array
    plane_friction: wp.array
    sphere_center: wp.array
    sphere_radius: wp.array
    sphere_friction: wp.array
    static_meshes: list
    static_mesh_ids: wp.array
    static_mesh_thickness: wp.array
    static_mesh_friction: wp.array
    point_body: wp.array
    body_point_start_wp: wp.array
    triangles: wp.array
    body_triangle_start: wp.array
    surfaces: dict
    meshes: list
    mesh_ids: wp.array
    pair_enabled: wp.array
    kinematic: list
    drive_node: wp.array
    drive_body: wp.array
    drive_local: wp.array
    edges: wp.array
    edge_faces: wp.array
    edge_body: wp.array
    body_edge_start: wp.array
    bvhs: list
    bvh_ids: wp.array
    crease_bvhs: list
    crease_bvh_ids: wp.array
    couplings: NodeCouplings
    rigid: NodeRigid | None
    cloth: NodeCloth


@dataclass
class NodeContacts:
    """Contacts of collision points with planes, static spheres and meshes and of surface
    vertices with other bodies' triangles, fixed capacity ``c`` (every point against every
    plane, sphere, mesh and other body); rows ``[:count[0]]`` hold this step's (``p`` points,
    ``s`` planes, ``k`` spheres, ``ms`` meshes, ``B`` bodies).

    Attributes
    ----------
    capacity : int
    count : wp.array(int32) [1]
    kind : wp.array(int32) [c]
        0: point vs plane, 1: surface vertex vs a triangle of another body, 2: edge vs edge,
        3: a rigid body's box or sphere primitive vs a plane or another primitive (``column``
        side a's body, ``point`` the rigid path's contact row, ``other`` side b's body or -1),
        4: point vs static sphere, 5: point vs static mesh.
    column : wp.array(int32) [c]
        The contact's column in ``carried`` (kinds 0, 1, 4, 5) or ``edge_carried`` (kind 2).
    point : wp.array(int32) [c]
        The collision point (global), or edge (global, kind 2); with its body and ``other`` it
        makes the contact's key (:func:`softvr.collision.contact_keys`, kinds POINT_PLANE,
        VERTEX_TRIANGLE, EDGE_EDGE, POINT_SPHERE, POINT_MESH).
    other : wp.array(int32) [c]
        The plane, sphere or mesh, or the body met.
    face : wp.array(int32) [c]; bary : wp.array(vec3d) [c]
        The triangle met (global, -1 for a plane) and the contact point's barycentric
        coordinates in it; for an edge pair the edge met (global) and (s, t, 0), where the
        closest points lie along the two edges.
    frame : wp.array(mat33d) [c]
        Rows: normal (out of side b, towards the point), tangent 1, tangent 2 (world).
    gap : wp.array(float64) [c] [m]
        Signed distance at the step's start.
    friction : wp.array(float64) [c]
    impulse : wp.array(vec3d) [c] [N s]
        (normal, tangent 1, tangent 2) impulse; the warm start in, the solution out.
    gap_after : wp.array(float64) [c] [m]
        Linearized gap at the step's end.
    stencil_count : wp.array(int32) [c]; stencil_nodes : wp.array2d(int32) [c, 16];
    stencil_weights : wp.array2d(float64) [c, 16]
        The contact's relative velocity is ``sum_k w_k v[node_k]`` (side a's nodes positive,
        side b's negative, each node once).
    carried : wp.array2d(vec3d) [p, s + B + k + ms] [N s]
        World impulse of each (point, plane), (vertex, body), (point, sphere) and (point, mesh)
        pair at the last step: the next warm start.
    hit, hit_face, hit_bary, hit_normal, hit_gap : wp.array2d [p, B]
        The vertex queries' findings, per (point, body).
    static_hit : wp.array2d(int32) [p, ms]; static_normal : wp.array2d(vec3) [p, ms];
    static_gap : wp.array2d(float32) [p, ms] [m]
        The static mesh queries' findings, per (point, mesh) (single precision, the BVHs').
    pair_edge, pair_st, pair_normal, pair_gap : wp.array2d [e, 2 B]
        The edge queries' findings (edge met, or -1), per (edge, slot).
    edge_carried : wp.array2d(vec3d) [e, 2 B] [N s]; edge_partner : wp.array2d(int32) [e, 2 B]
        World impulse of each edge pair at the last step, and the edge it was with.
    rigid_node : wp.array2d(int32) [c, 2]; rigid_lever : wp.array2d(vec3d) [c, 2] [m]
        The contact's rigid sides: angular node (-1: none) and lever arm, adding
        ``omega x lever`` to the relative velocity (:mod:`softvr.collision.node_rigid_detection`).
    area : wp.array(float64) [c] [m^2]
        Contact area (set only in scenes with adhesion: :class:`softvr.contact.NodeAdhesion`).
    stiffness : wp.array(float64) [c] [N/m]
        Implicit adhesive stiffness ``A C beta^2`` (eq. 4.16: ``k = dt^2 A C beta^2``; 0: none).
    slip : wp.array(vec3d) [c] [m]
        Tangential slip of a bonded contact since it bonded (world): its tangent rows' targets
        are ``-t . slip / dt``.
    """

    capacity: int
    count: wp.array
    kind: wp.array
    column: wp.array
    point: wp.array
    other: wp.array
    face: wp.array
    bary: wp.array
    frame: wp.array
    gap: wp.array
    friction: wp.array
    impulse: wp.array
    gap_after: wp.array
    stencil_count: wp.array
    stencil_nodes: wp.array
    stencil_weights: wp.array
    carried: wp.array
    hit: wp.array
    hit_face: wp.array
    hit_bary: wp.array
    hit_normal: wp.array
    hit_gap: wp.array
    static_hit: wp.array
    static_normal: wp.array
    static_gap: wp.array
    pair_edge: wp.array
    pair_st: wp.array
    pair_normal: wp.array
    pair_gap: wp.array
    edge_carried: wp.array
    edge_partner: wp.array
    rigid_node: wp.array
    rigid_lever: wp.array
    area: wp.array
    stiffness: wp.array
    slip: wp.array


@dataclass
class NodeState:
    """What changes from step to step (``n`` nodes, ``m`` tets, ``nb`` blocks).

    Attributes
    ----------
    q : wp.array(vec3d) [n] [m]
    v : wp.array(vec3d) [n] [m/s]
    fixed_velocity : wp.array(vec3d) [n] [m/s]
        Velocity of the fixed nodes over the next step (Control).
    kinematic_position : wp.array(vec3d) [k] [m]; kinematic_rotation : wp.array(mat33d) [k]
        Pose of each of ``NodeModel.kinematic`` at the step's start (Control: its script's).
    kinematic_velocity : wp.array(spatial_vectord) [k] [m/s, rad/s]
        Its velocity over the step (linear, world angular; Control).
    external : wp.array(vec3d) [n] [N]
        External node forces of the step (``Scene.external``; Control).
    rotations : wp.array(mat33d) [m]; element_forces : wp.array2d(vec3d) [m, 4] [N]
        The element terms at the step's start (R_e; f_e per tet node).
    rotated_gradients : wp.array2d(vec3d) [m, 4] [1/m]
        R_e g_a, each tet node's rotated shape-function gradient (written and read only where
        every tet is isotropic linear: :func:`softvr.dynamics.node_arrays.isotropic_terms`).
    blocks : wp.array(mat33d) [nb] [kg]; d_inv : wp.array(mat33d) [n] [1/kg]; b : wp.array(vec3d) [n] [kg m/s]
        ``A``, ``D_A^-1`` and ``b`` of eq. 5.2.
    v_hat : wp.array(vec3d) [n] [m/s]
        A sweep's Jacobi update.
    sweep_buffers : list of 3 wp.array(vec3d) [n] [m/s]
        The sweeps' velocities v^k-1, v^k, v^k+1 (rotating).
    diverged : wp.array(int32) [n]
        0, or why the step stopped at the node (``NODE_DIVERGENCE_REASONS``).
    point_x : wp.array(vec3d) [p] [m]; point_x32 : wp.array(vec3) [p] [m]
        Collision point positions at the step's start (single precision: the BVHs' vertices).
    point_u : wp.array(vec3d) [p] [m/s]
        Their predicted velocities over the step (for the speculative contacts).
    body_mean_u : wp.array(vec3d) [bodies] [m/s]
        Mean of each body's ``point_u``.
    edge_lower, edge_upper, edge_normal : wp.array(vec3) [e]; edge_sharp : wp.array(int32) [e]
        Each edge's box [m], unit mean normal and crease flag at the step's start.
    crease_lower, crease_upper : wp.array(vec3) [e] [m]
        The box of each crease or border edge, an empty one (lower 1e30, upper -1e30) for a smooth one.
    contacts : NodeContacts
    """

    q: wp.array
    v: wp.array
    fixed_velocity: wp.array
    kinematic_position: wp.array
    kinematic_rotation: wp.array
    kinematic_velocity: wp.array
    external: wp.array
    rotations: wp.array
    element_forces: wp.array
    rotated_gradients: wp.array
    blocks: wp.array
    d_inv: wp.array
    b: wp.array
    v_hat: wp.array
    sweep_buffers: list
    diverged: wp.array
    point_x: wp.array
    point_x32: wp.array
    point_u: wp.array
    body_mean_u: wp.array
    edge_lower: wp.array
    edge_upper: wp.array
    edge_normal: wp.array
    edge_sharp: wp.array
    crease_lower: wp.array
    crease_upper: wp.array
    contacts: NodeContacts


def node_model_supported(scene) -> bool:
    """Whether ``scene`` is one :class:`NodeModel` holds: FEM bodies (all co-rotational or all
    linear) and cloth bodies (at least one of them), rigid bodies (with or without a collision sphere or box), kinematic
    and fixed bodies (with or without one, where it meets no rigid body's of its kind), static planes,
    static spheres and meshes, couplings
    between them (each side an FEM body's embedded points or a kinematic, fixed or rigid body's
    points); adhesion; at most one set of collision points per body (an FEM or cloth body's
    :class:`~softvr.collision.EmbeddedPoints` with stencils of at most 4 nodes, a rigid, kinematic
    or fixed body's :class:`~softvr.dynamics.RigidPoints`) and each body's collision surface over
    its own points."""
    if not couplings_supported(scene):
        return False
    if _driven_primitive_meets_rigid(scene):
        return False
    if not any(isinstance(b, NODE_BODIES) for b in scene.bodies):
        return False
    if len({b.corotational for b in scene.bodies if type(b) is FemBody}) > 1:
        return False
    if not all(type(b) in (FemBody, ClothBody, RigidBody, KinematicBody, FixedBody) for b in scene.bodies):
        return False
    owners = [c.body for c in scene._colliders]
    if len(set(owners)) != len(owners):
        return False
    for c in scene._colliders:
        body = scene.bodies[c.body]
        kind = EmbeddedPoints if isinstance(body, NODE_BODIES) else RigidPoints
        if not isinstance(c.points, kind) or c.points.body is not body:
            return False
        if isinstance(c.points, EmbeddedPoints) and c.points.nodes.shape[1] > STENCIL:
            return False
    points = {c.body: c.points for c in scene._colliders}
    return all(points.get(s.body_index) is s.points for s in scene._surfaces)


def _driven_primitive_meets_rigid(scene) -> bool:
    """Whether a kinematic or fixed body's collision sphere or box would meet a rigid body's of
    the same kind (two spheres or two boxes meet by their primitives, as per object; a sphere
    and a box by their surfaces). The arrays' primitive detection holds the rigid bodies alone
    (it has no driven side), so such a pair would lose its contacts; a driven primitive that the
    collision filters keep from every rigid one (candy-adhesive's hand) is harmless: against
    planes it cannot be moved."""
    for shapes in (scene._sphere_bodies, scene._box_bodies):
        kinds = [(i, type(scene.bodies[i])) for i, _ in shapes]
        for i, kind_i in kinds:
            for j, kind_j in kinds:
                if kind_i in (KinematicBody, FixedBody) and kind_j is RigidBody and scene.collision_enabled(i, j):
                    return True
    return False


def _i32(values, device):
    return wp.array(np.ascontiguousarray(values, np.int32), dtype=wp.int32, device=device)


def _f64(values, device, dtype=wp.float64):
    return wp.array(np.ascontiguousarray(values, np.float64), dtype=dtype, device=device)


def _pattern(tets: np.ndarray, n: int, extra: np.ndarray) -> tuple:
    """Block-CSR pattern of ``A`` (the tets' blocks and the ``extra`` keys ``row n + col``: the
    couplings'), the gather lists of its blocks and of the node forces, and the blocks the
    assembly sums with their transposed partners."""
    # Element block 16 e + 4 a + b (rows of the tet's node a, columns of its node b) is entry
    # 16 e + 4 a + b of these; one stable sort of the keys groups the entries by block, each
    # block's in element order.
    tet_keys = (np.repeat(tets, 4, axis=1).astype(np.int64) * n + np.tile(tets, (1, 4))).ravel()
    every = np.concatenate([tet_keys, np.asarray(extra, np.int64)])
    order = np.argsort(every, kind="stable")
    ordered = every[order]
    first = np.concatenate([[True], ordered[1:] != ordered[:-1]])
    keys = ordered[first]
    from_tets = order < len(tet_keys)
    contrib = order[from_tets]
    contrib_start = np.searchsorted((np.cumsum(first) - 1)[from_tets], np.arange(len(keys) + 1))
    block_row, block_col = keys // n, keys % n
    row_start = np.searchsorted(block_row, np.arange(n + 1))
    mirror_keys = block_col * n + block_row
    mirror = np.minimum(np.searchsorted(keys, mirror_keys), len(keys) - 1)
    mirror = np.where(keys[mirror] == mirror_keys, mirror, -1)
    assembled = np.flatnonzero((block_col >= block_row) | (mirror < 0))
    nodes = tets.ravel()
    force = np.argsort(nodes, kind="stable")  # element force 4 e + a is entry 4 e + a of the tets
    force_start = np.searchsorted(nodes[force], np.arange(n + 1))
    return block_row, block_col, row_start, contrib_start, contrib, force_start, force, assembled, mirror


def _point_stencils(scene, bodies, node_start, point_start) -> tuple:
    """Stencil nodes and weights [p, 4] (global; -1: unused), margins [p] [m] and margins
    against planes [p] [m] of every collision point; a kinematic body's points are its own
    nodes, weight 1, a rigid body's its linear node (the angular one is a rigid side); a plane
    margin of -inf for a point that meets no plane (a rigid body's with a primitive: the
    primitive meets them exactly; its points still meet static spheres and meshes)."""
    primitive = {i for i, _ in scene._sphere_bodies + scene._box_bodies}
    p = int(point_start[-1])
    nodes = np.full((p, STENCIL), -1, np.int64)
    weights = np.zeros((p, STENCIL))
    margin = np.zeros(p)
    plane_margin = np.zeros(p)
    for c in scene._colliders:
        rows = slice(point_start[c.body], point_start[c.body + 1])
        if isinstance(bodies[c.body], NODE_BODIES):
            k = c.points.nodes.shape[1]
            nodes[rows, :k] = c.points.nodes + node_start[c.body]
            weights[rows, :k] = c.points.weights
        elif type(bodies[c.body]) is RigidBody:
            nodes[rows, 0] = node_start[c.body]
            weights[rows, 0] = 1.0
        else:
            nodes[rows, 0] = node_start[c.body] + np.arange(rows.stop - rows.start)
            weights[rows, 0] = 1.0
        margin[rows] = c.margin
        plane_margin[rows] = -np.inf if type(bodies[c.body]) is RigidBody and c.body in primitive else c.margin
    return nodes, weights, margin, plane_margin


def build_node_model(scene, device: str = "cpu") -> tuple[NodeModel, NodeState]:
    """The arrays of a scene :func:`node_model_supported` accepts, at its bodies' current state."""
    bodies = scene.bodies
    colliders = {c.body: c for c in scene._colliders}
    point_counts = [len(colliders[i].points.positions()) if i in colliders else 0 for i in range(len(bodies))]
    fem = [type(b) is FemBody for b in bodies]  # bodies with tets
    nodal = [isinstance(b, NODE_BODIES) for b in bodies]  # bodies of free nodes: FEM and cloth
    rigid = [type(b) is RigidBody for b in bodies]
    # A kinematic body's nodes: where its points (collision, then coupling) are, at its
    # velocity; driven, so no mass acts. A rigid body's: its linear and its angular velocity.
    driven = driven_points(scene, colliders)
    node_counts = [len(b.q) if f else 2 if rigid[i] else (0 if driven[i] is None else len(driven[i].local))
                   for i, (b, f) in enumerate(zip(bodies, nodal))]
    node_start = np.cumsum([0] + node_counts)
    point_start = np.cumsum([0] + point_counts)
    n, p, nbody = int(node_start[-1]), int(point_start[-1]), len(bodies)
    tets = np.concatenate([np.zeros((0, 4), np.int64)]
                          + [b.tets + node_start[i] for i, b in enumerate(bodies) if fem[i]]).astype(np.int64)
    m = len(tets)
    rigid_rows = np.repeat(rigid, node_counts)
    solved_rows = np.repeat(nodal, node_counts) | rigid_rows
    springs = coupling_springs(scene, node_start, colliders)
    terms = coupling_blocks(springs, solved_rows)
    cloth = cloth_springs(scene, node_start)
    block_row, block_col, row_start, contrib_start, contrib, force_start, force, assembled, mirror = \
        _pattern(tets, n, np.concatenate([terms[0], cloth_block_keys(scene, node_start, cloth[0])]))
    kinematic = [i for i in range(nbody) if not nodal[i] and not rigid[i]]

    def per_node(nodal_value, other_value):
        return np.concatenate([nodal_value(b) if f else np.full((k,) + np.shape(other_value), other_value)
                               for b, f, k in zip(bodies, nodal, node_counts)])

    def positions(b, i):
        if rigid[i]:
            return np.array([b.position, np.zeros(3)])  # the angular node has no position
        return b.q if nodal[i] else (driven[i].positions() if driven[i] is not None else np.zeros((0, 3)))

    scale = [1e3 * max(float(np.ptp(b.rest, axis=0).max()), 1e-9) if f else np.inf for b, f in zip(bodies, nodal)]
    point_nodes, point_weights, point_margin, plane_margin = _point_stencils(scene, bodies, node_start, point_start)
    planes = scene.planes
    normals = np.array([pl.unit_normal() for pl in planes], float).reshape(-1, 3)
    offsets = np.array([float(np.asarray(pl.point, float) @ nrm) for pl, nrm in zip(planes, normals)])
    surfaces = {s.body_index: s for s in scene._surfaces}
    tri_counts = [len(surfaces[i].triangles) if i in surfaces else 0 for i in range(nbody)]
    tri_start = np.cumsum([0] + tri_counts)
    triangles = np.concatenate([np.zeros((0, 3), np.int64)] + [surfaces[i].triangles + point_start[i]
                                                               for i in range(nbody) if i in surfaces])
    pair = np.zeros((nbody, nbody), np.int32)
    primitive = {i: "sphere" for i, _ in scene._sphere_bodies} | {i: "box" for i, _ in scene._box_bodies}
    for a in surfaces:
        for b in surfaces:
            # Two boxes or two spheres meet by their primitives, exactly (as per object).
            pair[a, b] = int(a != b and scene.collision_enabled(a, b) and primitive.get(a, "a") != primitive.get(b, "b"))
    edged = [i for i in surfaces if pair[i].any()] if scene.edge_contacts else []
    edge_sets = {i: surfaces[i].edge_set for i in edged}
    edge_counts = [len(edge_sets[i].edges) if i in edge_sets else 0 for i in range(nbody)]
    edge_start = np.cumsum([0] + edge_counts)
    edges = np.concatenate([np.zeros((0, 2), np.int64)] + [edge_sets[i].edges + point_start[i] for i in edged])
    edge_faces = np.concatenate([np.zeros((0, 2), np.int64)] + [np.where(edge_sets[i].adjacent >= 0,
                                                                         edge_sets[i].adjacent + tri_start[i], -1)
                                                                for i in edged])
    e = len(edges)
    d = device
    point_x32 = wp.zeros(max(p, 1), dtype=wp.vec3, device=d)
    meshes, mesh_ids = [], np.zeros(nbody, np.uint64)
    if pair.any():
        # Each body's BVH over its points' slice of point_x32, built at the current positions.
        for c in scene._colliders:
            point_x32[int(point_start[c.body]):int(point_start[c.body + 1])].assign(
                np.asarray(c.points.positions(), np.float32))
        for i, surface in surfaces.items():
            mesh = wp.Mesh(points=point_x32[int(point_start[i]):int(point_start[i + 1])],
                           indices=wp.array(surface.triangles.ravel().astype(np.int32), dtype=wp.int32, device=d))
            meshes.append(mesh)
            mesh_ids[i] = mesh.id
    x32 = point_x32.numpy()
    edge_lower: wp.array = wp.array(np.minimum(x32[edges[:, 0]], x32[edges[:, 1]]).reshape(-1, 3), dtype=wp.vec3, device=d)
    edge_upper: wp.array = wp.array(np.maximum(x32[edges[:, 0]], x32[edges[:, 1]]).reshape(-1, 3), dtype=wp.vec3, device=d)
    crease_lower, crease_upper = wp.clone(edge_lower), wp.clone(edge_upper)
    bvhs, bvh_ids, crease_bvhs, crease_bvh_ids = [], np.zeros(nbody, np.uint64), [], np.zeros(nbody, np.uint64)
    for i in edged:
        rows = slice(int(edge_start[i]), int(edge_start[i + 1]))
        bvh = wp.Bvh(edge_lower[rows], edge_upper[rows])
        bvhs.append(bvh)
        bvh_ids[i] = bvh.id
        # The same boxes build the same tree; the detection refits it to the creases' boxes.
        crease = wp.Bvh(crease_lower[rows], crease_upper[rows])
        crease_bvhs.append(crease)
        crease_bvh_ids[i] = crease.id
    static_meshes = [wp.Mesh(points=wp.array(m.vertices, dtype=wp.vec3, device=d),
                             indices=wp.array(m.triangles.ravel(), dtype=wp.int32, device=d)) for m in scene.meshes]
    f64_nodes = [b.mass if f else np.ones(k) for b, f, k in zip(bodies, nodal, node_counts)]
    fem_bodies = [b for b, f in zip(bodies, fem) if f]
    model = NodeModel(
        device=d, node_count=n, tet_count=m, block_count=len(block_row), point_count=p,
        body_node_start=node_start, body_point_start=point_start,
        rest=_f64(np.concatenate([b.rest if nodal[i] else positions(b, i) for i, b in enumerate(bodies)]), d, wp.vec3d),
        mass=_f64(np.concatenate(f64_nodes), d),
        node_alpha=_f64(per_node(lambda b: np.full(len(b.q), b.alpha if isinstance(b, ClothBody) else b.material.alpha),
                                 0.0), d),
        fixed=_i32(per_node(lambda b: b.fixed, 1) * ~np.repeat(rigid, node_counts), d),
        speed_limit=_f64(np.concatenate([np.full(k, s) for k, s in zip(node_counts, scale)]), d),
        tets=_i32(tets, d),
        dm_inv=_f64(np.concatenate([np.zeros((0, 3, 3))] + [b._dm_inv for b in fem_bodies]), d, wp.mat33d),
        ke=_f64(np.concatenate([np.zeros((0, 12, 12))] + [b._ke for b in fem_bodies]).reshape(m, 4, 3, 4, 3)
                .transpose(0, 1, 3, 2, 4).reshape(m, 16, 3, 3), d, wp.mat33d),
        tet_beta=_f64(np.concatenate([np.zeros(0)] + [np.full(len(b.tets), b.material.beta) for b in fem_bodies]), d),
        corotational=bool(fem_bodies[0].corotational) if fem_bodies else True,
        block_row=_i32(block_row, d), block_col=_i32(block_col, d), row_start=_i32(row_start, d),
        contrib_start=_i32(contrib_start, d), contrib=_i32(contrib, d), assembled=_i32(assembled, d),
        block_mirror=_i32(mirror, d),
        force_start=_i32(force_start, d), force=_i32(force, d),
        point_nodes=_i32(point_nodes, d), point_weights=_f64(point_weights, d), point_margin=_f64(point_margin, d),
        plane_margin=_f64(plane_margin, d),
        plane_normal=_f64(normals, d, wp.vec3d), plane_offset=_f64(offsets, d),
        plane_friction=_f64([pl.friction for pl in planes], d),
        sphere_center=_f64(np.array([sp.center for sp in scene.spheres], float).reshape(-1, 3), d, wp.vec3d),
        sphere_radius=_f64([sp.radius for sp in scene.spheres], d),
        sphere_friction=_f64([sp.friction for sp in scene.spheres], d),
        static_meshes=static_meshes, static_mesh_ids=wp.array([m.id for m in static_meshes], dtype=wp.uint64, device=d),
        static_mesh_thickness=wp.array([m.thickness for m in scene.meshes], dtype=wp.float32, device=d),
        static_mesh_friction=_f64([m.friction for m in scene.meshes], d),
        point_body=_i32(np.repeat(np.arange(nbody), point_counts), d), body_point_start_wp=_i32(point_start, d),
        triangles=_i32(triangles.reshape(-1, 3), d), body_triangle_start=_i32(tri_start, d),
        surfaces=surfaces, meshes=meshes, mesh_ids=wp.array(mesh_ids, dtype=wp.uint64, device=d),
        pair_enabled=_i32(pair, d), kinematic=kinematic,
        drive_node=_i32(np.concatenate([np.arange(node_start[i], node_start[i + 1]) for i in kinematic] + [[]]), d),
        drive_body=_i32(np.concatenate([np.full(node_counts[i], j) for j, i in enumerate(kinematic)] + [[]]), d),
        drive_local=_f64(np.concatenate([np.zeros((0, 3))] + [driven[i].local for i in kinematic
                                                               if driven[i] is not None]), d, wp.vec3d),
        edges=_i32(edges.reshape(-1, 2), d), edge_faces=_i32(edge_faces.reshape(-1, 2), d),
        edge_body=_i32(np.repeat(np.arange(nbody), edge_counts), d), body_edge_start=_i32(edge_start, d),
        bvhs=bvhs, bvh_ids=wp.array(bvh_ids, dtype=wp.uint64, device=d), crease_bvhs=crease_bvhs,
        crease_bvh_ids=wp.array(crease_bvh_ids, dtype=wp.uint64, device=d),
        couplings=build_node_couplings(springs, terms, solved_rows, rigid_rows,
                                       block_row.astype(np.int64) * n + block_col, driven, d),
        rigid=build_node_rigid(scene, node_start, point_start, d),
        cloth=build_node_cloth(cloth, n, block_row.astype(np.int64) * n + block_col, d))
    surface_rows = int(sum(point_counts[a] * int(pair[a].sum()) for a in range(nbody)))
    statics = len(planes) + len(scene.spheres) + len(scene.meshes)
    capacity = max(p * statics + surface_rows + PAIRS_PER_EDGE * e
                   + (model.rigid.model.contact_capacity if model.rigid is not None else 0), 1)
    wide = (max(p, 1), nbody)
    static_wide = (max(p, 1), max(len(scene.meshes), 1))
    edge_wide = (max(e, 1), PAIRS_PER_EDGE * nbody)
    contacts = NodeContacts(
        capacity=capacity, count=wp.zeros(1, dtype=wp.int32, device=d),
        kind=wp.zeros(capacity, dtype=wp.int32, device=d), column=wp.zeros(capacity, dtype=wp.int32, device=d),
        point=wp.zeros(capacity, dtype=wp.int32, device=d),
        other=wp.zeros(capacity, dtype=wp.int32, device=d), face=wp.zeros(capacity, dtype=wp.int32, device=d),
        bary=wp.zeros(capacity, dtype=wp.vec3d, device=d),
        frame=wp.zeros(capacity, dtype=wp.mat33d, device=d), gap=wp.zeros(capacity, dtype=wp.float64, device=d),
        friction=wp.zeros(capacity, dtype=wp.float64, device=d),
        impulse=wp.zeros(capacity, dtype=wp.vec3d, device=d), gap_after=wp.zeros(capacity, dtype=wp.float64, device=d),
        stencil_count=wp.zeros(capacity, dtype=wp.int32, device=d),
        stencil_nodes=wp.full((capacity, CONTACT_STENCIL), -1, dtype=wp.int32, device=d),
        stencil_weights=wp.zeros((capacity, CONTACT_STENCIL), dtype=wp.float64, device=d),
        carried=wp.zeros((max(p, 1), statics + nbody), dtype=wp.vec3d, device=d),
        hit=wp.zeros(wide, dtype=wp.int32, device=d), hit_face=wp.zeros(wide, dtype=wp.int32, device=d),
        hit_bary=wp.zeros(wide, dtype=wp.vec3d, device=d), hit_normal=wp.zeros(wide, dtype=wp.vec3d, device=d),
        hit_gap=wp.zeros(wide, dtype=wp.float64, device=d),
        static_hit=wp.zeros(static_wide, dtype=wp.int32, device=d),
        static_normal=wp.zeros(static_wide, dtype=wp.vec3, device=d),
        static_gap=wp.zeros(static_wide, dtype=wp.float32, device=d),
        pair_edge=wp.full(edge_wide, -1, dtype=wp.int32, device=d),
        pair_st=wp.zeros(edge_wide, dtype=wp.vec3d, device=d),
        pair_normal=wp.zeros(edge_wide, dtype=wp.vec3d, device=d),
        pair_gap=wp.zeros(edge_wide, dtype=wp.float64, device=d),
        edge_carried=wp.zeros(edge_wide, dtype=wp.vec3d, device=d),
        edge_partner=wp.full(edge_wide, -1, dtype=wp.int32, device=d),
        rigid_node=wp.full((capacity, 2), -1, dtype=wp.int32, device=d),
        rigid_lever=wp.zeros((capacity, 2), dtype=wp.vec3d, device=d),
        area=wp.zeros(capacity, dtype=wp.float64, device=d), stiffness=wp.zeros(capacity, dtype=wp.float64, device=d),
        slip=wp.zeros(capacity, dtype=wp.vec3d, device=d))

    def vec():
        return wp.zeros(n, dtype=wp.vec3d, device=d)

    q = np.concatenate([positions(b, i) for i, b in enumerate(bodies)])
    state = NodeState(
        q=_f64(q, d, wp.vec3d),
        v=_f64(np.concatenate([b.v if nodal[i] else np.reshape(b.v, (2, 3)) if rigid[i] else np.zeros((k, 3))
                               for i, (b, k) in enumerate(zip(bodies, node_counts))]), d, wp.vec3d),
        fixed_velocity=_f64(np.concatenate([b.fixed_velocity if nodal[i] else np.zeros((k, 3))
                                            for i, (b, k) in enumerate(zip(bodies, node_counts))]), d, wp.vec3d),
        kinematic_position=wp.zeros(len(kinematic), dtype=wp.vec3d, device=d),
        kinematic_rotation=wp.zeros(len(kinematic), dtype=wp.mat33d, device=d),
        kinematic_velocity=wp.zeros(len(kinematic), dtype=wp.spatial_vectord, device=d),
        external=vec(), rotations=wp.zeros(m, dtype=wp.mat33d, device=d),
        element_forces=wp.zeros((m, 4), dtype=wp.vec3d, device=d),
        rotated_gradients=wp.zeros((m, 4), dtype=wp.vec3d, device=d),
        blocks=wp.zeros(len(block_row), dtype=wp.mat33d, device=d), d_inv=wp.zeros(n, dtype=wp.mat33d, device=d),
        b=vec(), v_hat=vec(), sweep_buffers=[vec(), vec(), vec()], diverged=wp.zeros(n, dtype=wp.int32, device=d),
        point_x=wp.zeros(max(p, 1), dtype=wp.vec3d, device=d), point_x32=point_x32,
        point_u=wp.zeros(max(p, 1), dtype=wp.vec3d, device=d),
        body_mean_u=wp.zeros(nbody, dtype=wp.vec3d, device=d), edge_lower=edge_lower, edge_upper=edge_upper,
        edge_normal=wp.zeros(max(e, 1), dtype=wp.vec3, device=d),
        edge_sharp=wp.zeros(max(e, 1), dtype=wp.int32, device=d), crease_lower=crease_lower,
        crease_upper=crease_upper, contacts=contacts)
    return model, state
