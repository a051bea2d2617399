"""The FEM and cloth bodies of a whole scene on arrays: element terms, the step matrix ``A`` of
thesis eq. 5.2 in 3x3 node blocks with its right-hand side (the cloths' springs included), the
kinematic bodies' driven nodes, the sweeps' first guess and the integration, as recorded
launches replayed every step (:class:`softvr.sim.NodeModel` / :class:`softvr.sim.NodeState`, or
any objects with those attributes; kernels in :mod:`softvr.dynamics._node_kernels` and
:mod:`softvr.dynamics._node_cloth_kernels`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import warp as wp
from scipy.sparse.csgraph import connected_components

from softvr.device import blocked_replayer, in_order, load_kernels, replayer
from softvr.dynamics import _node_cloth_kernels as _c
from softvr.dynamics import _node_kernels as _k

__all__ = ["ISOTROPIC_MISFIT", "NODE_DIVERGENCE_REASONS", "SHARE_MEMORY", "fixed_only", "free_bodies",
           "isotropic_terms", "record_drive", "record_elements", "record_integrate", "record_start", "record_system",
           "shape_gradients", "shared_bodies"]

#: What a nonzero ``NodeState.diverged`` entry means (the divergence report names it).
NODE_DIVERGENCE_REASONS = {_k.NAN_VELOCITY: "NaN/inf", _k.TOO_FAST: "speed above 1000 body sizes per second"}


#: The weight a step's solve keeps, a step later, in the fit of the share of the velocity change
#: that the first guess carries on (:func:`_node_kernels.share_total`): ~10 steps of memory.
#: Measured on shoulder.toml (session 13, 600 steps, sweeps a step, deterministic): the whole
#: change carried 18.58; the fit over the last step alone (0) 17.68, 0.5 17.24, 0.9 16.79; a
#: fixed half 16.81. A fit, not a fixed share: a uniformly accelerated body carries all of it.
SHARE_MEMORY = 0.9


def fixed_only(model) -> tuple[np.ndarray, np.ndarray]:
    """The tets [m] with all four nodes fixed and the entries of ``model.assembled`` [na] whose
    block joins two fixed nodes (the bone of a CT: 1 354 of 5 915 tets, 3 007 of 10 330 blocks
    on the head), neither node coupled nor a cloth's (their blocks are added to after assembly).

    Nothing reads them: a fixed node's velocity is prescribed, so the sweeps (Jacobi and
    Gauss-Seidel), the factored solve (A_0 is factored over the free nodes), the spectrum
    bounds, the coarse level and the contacts' metrics read only free rows of ``A``, ``D_A^-1``
    and ``b`` (a fixed-fixed block sits in a fixed row), and a free node's rotation only its
    own tets'. Their entries keep their first values (zero). Checked: q and v after 60 steps
    of palpation.toml, candy.toml and shoulder.toml (haptics off) bit-identical."""
    fixed = model.fixed.numpy() != 0
    fixed[model.couplings.node.numpy()] = False
    fixed[model.cloth.node.numpy()] = False
    tets = model.tets.numpy().reshape(-1, 4)
    k = model.assembled.numpy()
    return fixed[tets].all(axis=1), fixed[model.block_row.numpy()[k]] & fixed[model.block_col.numpy()[k]]


def record_elements(model, state, *, keep: float = 0.0, turned: wp.array | None = None) -> Callable[[], None]:
    """A replay writing the rotation and elastic forces [N] (``state.rotations``,
    ``state.element_forces``) at ``state.q`` of every tet but those of fixed nodes only
    (:func:`fixed_only`), split over the CPU cores (from the Lame form where every tet is
    isotropic linear, :func:`isotropic_terms`). Each rotation starts from the one it replaces
    (last step's: ``_fem_kernels.warm_polar_rotation``; zeros go the cold way).

    With ``keep`` > 0 [rad] a tet's terms lag its nodes by at most ``keep``: its rotation stays
    last step's where that is within ``keep`` of the polar rotation
    (``_fem_kernels.lagged_polar_rotation``), and its rotation and forces stay as they are
    while each of its nodes is within ``keep / sum_a |g_a|`` [m] of where they were computed
    (g_a the shape functions' gradients [1/m]: F = sum_a x_a g_a^T then moved by at most
    ``keep``, so the held R_e is within ~2 ``keep`` of the polar rotation and the held forces
    are those of a strain within ``keep``). ``turned`` [m] (int32): 1 where a tet's rotation
    changed, else 0 (for :func:`record_system`)."""
    live = np.flatnonzero(~fixed_only(model)[0])
    live_d: wp.array = wp.array(live, dtype=wp.int32, device=model.device)
    d = model.device
    if turned is None:
        turned = wp.zeros(len(model.tets), dtype=wp.int32, device=d)
    dm_inv = model.dm_inv.numpy()
    reach = keep / np.maximum(np.linalg.norm(shape_gradients(dm_inv), axis=2).sum(axis=1), 1e-300)
    hold: wp.array = wp.array(reach, dtype=wp.float64, device=d)
    # Nowhere yet (1e300: its distance squared is inf): the first replay computes every tet.
    held = wp.full((len(model.tets), 4), wp.vec3d(1e300, 1e300, 1e300), dtype=wp.vec3d, device=d)
    lag = [float(keep), int(keep > 0.0), hold, held, state.rotations, turned, state.element_forces]
    isotropic = isotropic_terms(model.ke.numpy(), dm_inv)
    if isotropic is None:
        return blocked_replayer(_k.element_terms, len(live),
                                [state.q, model.rest, model.tets, model.dm_inv, model.ke, int(model.corotational),
                                 live_d, *lag], d, min_chunk=512)
    gradients, lame = isotropic
    return blocked_replayer(_k.element_terms_isotropic, len(live),
                            [state.q, model.rest, model.tets, model.dm_inv, wp.array(gradients, dtype=wp.vec3d, device=d),
                             wp.array(lame, dtype=wp.vec2d, device=d), int(model.corotational), live_d, *lag,
                             state.rotated_gradients], d, min_chunk=512)


#: Largest relative misfit |K_e - K_iso|_F / |K_e|_F of an element stiffness to the isotropic
#: form for :func:`record_system` to assemble it as isotropic (K_e = V B^T C B in float64 fits
#: to ~1e-15; an anisotropic C misfits by O(1)).
ISOTROPIC_MISFIT = 1e-12


def shape_gradients(dm_inv: np.ndarray) -> np.ndarray:
    """The linear tets' shape-function gradients g_a [m, 4, 3] [1/m] from Dm^-1 [m, 3, 3] [1/m]:
    its rows for nodes 1..3, minus their sum for node 0 (F = Ds Dm^-1 = sum_a x_a g_a^T)."""
    return np.concatenate([-dm_inv.sum(axis=1, keepdims=True), dm_inv], axis=1)


def isotropic_terms(ke: np.ndarray, dm_inv: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The shape functions' rest gradients g_a [m, 4, 3] [1/m] (:func:`shape_gradients`) and V (lambda, mu) [m, 2] [N/m] of every tet, such that
    ``ke[e, 4 a + b]`` [m, 16, 3, 3] [N/m] = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I)
    (the isotropic linear tet, K_e = V B^T C B) within :data:`ISOTROPIC_MISFIT`; None if any
    tet's stiffness is not of that form (least squares over its 144 entries)."""
    grad = shape_gradients(dm_inv)
    if not len(ke):  # a scene of cloths only
        return grad, np.zeros((0, 2))
    ga = np.repeat(grad, 4, axis=1)  # [m, 16, 3]: g_a of entry 4 a + b
    gb = np.tile(grad, (1, 4, 1))
    basis_lam = ga[..., :, None] * gb[..., None, :]
    basis_mu = gb[..., :, None] * ga[..., None, :] + np.einsum("eki,eki->ek", ga, gb)[..., None, None] * np.eye(3)
    basis = np.stack([basis_lam, basis_mu], axis=1).reshape(len(ke), 2, -1)  # [m, 2, 144]
    flat = ke.reshape(len(ke), -1)
    lame = np.linalg.solve(basis @ basis.transpose(0, 2, 1), basis @ flat[:, :, None])[:, :, 0]
    misfit = np.linalg.norm(flat - np.einsum("ek,ekj->ej", lame, basis), axis=1)
    if np.any(misfit > ISOTROPIC_MISFIT * np.linalg.norm(flat, axis=1)):
        return None
    return grad, lame


def record_system(model, state, dt: float, gravity, *, turned: wp.array | None = None
                  ) -> tuple[Callable[[], None], Callable[[], None]]:
    """Replays writing ``A`` (``state.blocks``, ``state.d_inv``) and ``b`` (``state.b``) of a
    step of ``dt`` [s] under ``gravity`` [3] [m/s^2] from the element terms and the cloth
    springs (``model.cloth``: :class:`softvr.sim._node_cloth.NodeCloth`) at ``state.q``; the
    second (``b``) reads the springs' forces the first wrote. Blocks of fixed nodes only
    (:func:`fixed_only`) are not assembled. With ``turned`` (:func:`record_elements`'), a
    replay after the first assembles only the blocks of the tets whose rotation changed and
    those the cloth's and the couplings' springs add to after it (:func:`_added_to`: kept, they
    would take the springs' terms twice)."""
    assembled = model.assembled.numpy()[~fixed_only(model)[1]]
    blocks = [model.block_mirror, model.block_row, model.block_col, model.contrib_start, model.contrib]
    flags = wp.zeros(1, dtype=wp.int32, device=model.device) if turned is None else turned
    isotropic = isotropic_terms(model.ke.numpy(), model.dm_inv.numpy())
    if isotropic is None:
        head = blocks + [state.rotations, model.ke, model.tet_beta]
        assembly = _k.assemble
    else:  # the rotated gradients of record_elements' replay (the same choice)
        scale = dt * model.tet_beta.numpy() + dt * dt
        head = blocks + [state.rotated_gradients,
                         wp.array(scale[:, None] * isotropic[1], dtype=wp.vec2d, device=model.device)]
        assembly = _k.assemble_isotropic

    def replay(which: np.ndarray, lagging: int) -> Callable[[], None]:
        return blocked_replayer(assembly, len(which), [wp.array(which, dtype=wp.int32, device=model.device)] + head
                                + [model.mass, model.node_alpha, float(dt), flags, lagging, state.blocks, state.d_inv],
                                model.device, min_chunk=1024)

    if turned is None:
        assemble = replay(assembled, 0)
    else:
        added = np.isin(assembled, _added_to(model))
        rest = assembled[~added]
        assemble = in_order(replay(assembled[added], 0), _first_then(replay(rest, 0), replay(rest, 1)))
    load_kernels(_k.right_hand_side, model.device)
    rhs = wp.launch(_k.right_hand_side, dim=model.node_count, device=model.device, record_cmd=True,
                    inputs=[model.force_start, model.force, state.element_forces, model.mass, state.v, state.external,
                            wp.vec3d(*np.asarray(gravity, float)), float(dt), state.b])
    cloth = model.cloth
    if not cloth.spring_count:  # Warp records no launch of 0 threads
        return assemble, replayer(rhs)
    for kernel in (_c.spring_terms, _c.spring_blocks, _c.spring_forces):
        load_kernels(kernel, model.device)
    terms = wp.launch(_c.spring_terms, dim=cloth.spring_count, device=model.device, record_cmd=True,
                      inputs=[cloth.springs, cloth.rest_length, cloth.stiffness, cloth.damping, state.q, float(dt),
                              cloth.spring_block, cloth.spring_force])
    blocks = wp.launch(_c.spring_blocks, dim=cloth.block.shape[0], device=model.device, record_cmd=True,
                       inputs=[cloth.block, cloth.block_entry_start, cloth.block_entry, cloth.spring_block,
                               model.block_row, model.block_col, state.blocks, state.d_inv])
    forces = wp.launch(_c.spring_forces, dim=cloth.node.shape[0], device=model.device, record_cmd=True,
                       inputs=[cloth.node, cloth.node_entry_start, cloth.node_entry, cloth.spring_force, float(dt),
                               state.b])
    return in_order(assemble, replayer(terms), replayer(blocks)), in_order(replayer(rhs), replayer(forces))


def _added_to(model) -> np.ndarray:
    """The blocks of ``A`` [k] that the cloth's and the couplings' springs add to after the
    assembly (``model.cloth.block``, ``model.couplings.block``), with their transposes: the
    assembly writes one of each transposed pair and the other with it, and the springs leave
    out a driven node's row (its block on a solved node's column has no partner there)."""
    springs = np.concatenate([model.cloth.block.numpy(), model.couplings.block.numpy()])
    mirror = model.block_mirror.numpy()[springs]
    return np.union1d(springs, mirror[mirror >= 0])


def _first_then(first: Callable[[], None], then: Callable[[], None]) -> Callable[[], None]:
    """A replay that runs ``first`` on its first call and ``then`` on every later one."""
    calls = [first]

    def replay() -> None:
        calls[0]()
        calls[0] = then

    return replay


def record_drive(model, state) -> Callable[[], None]:
    """A replay setting the kinematic and fixed bodies' driven nodes (``state.q``, ``v``,
    ``fixed_velocity``) from their poses and velocities (``state.kinematic_*``)."""
    count = model.drive_node.shape[0]
    if not count:
        return in_order()
    load_kernels(_k.drive, model.device)
    return replayer(wp.launch(_k.drive, dim=count, device=model.device, record_cmd=True,
                              inputs=[model.drive_node, model.drive_body, model.drive_local, state.kinematic_position,
                                      state.kinematic_rotation, state.kinematic_velocity, state.q, state.v,
                                      state.fixed_velocity]))


def free_bodies(model) -> np.ndarray:
    """Which bodies [B] bool no chain of ``A``'s blocks (tets, springs, couplings) ties to a
    fixed or driven node: only gravity, external forces and contacts change their momentum,
    as over their component ``1^T A = 1^T M``. A held body's momentum changes by its fixed
    nodes' reactions too: the shoulder's tissues all hang on the bones (candy-adhesive.toml:
    the candies free, the Jell-O, the hand and the pulled candy held)."""
    n = model.node_count
    row = np.repeat(np.arange(n), np.diff(model.row_start.numpy()))
    graph = sp.coo_matrix((np.ones(len(row)), (row, model.block_col.numpy())), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    held = np.isin(label, label[model.fixed.numpy() != 0])
    start = np.asarray(model.body_node_start)
    return np.array([not held[a:b].any() for a, b in zip(start[:-1], start[1:])], bool)


def shared_bodies(model) -> np.ndarray:
    """Which bodies [B] bool take a fitted share of last step's change in the first guess
    (:func:`record_start`): the held ones (not :func:`free_bodies`) whose surfaces no free
    body's can touch (``model.pair_enabled`` [B, B], either way). A free body carries all of its
    change, for its momentum; a contact between it and a held body carrying a share starts the
    contact passes from two guesses erring apart. Measured (sweeps a step, haptics off): the
    share on every held body took shoulder.toml 18.83 -> 16.30 (300 steps), the arthroscopy
    14.65 -> 11.41 (no free body in either), but candy-adhesive.toml, whose held Jell-O the free
    candies land on, 72.8 -> 76.2 (mean of 4 runs each, gravity nudged by 0 to 3e-12 of itself:
    the landing's sweep counts spread by +-1.6 a step under rounding-size nudges); candy.toml
    76.0 -> 70.5 (one run) and the adhesion bench's two runs within that spread."""
    free = free_bodies(model)
    pairs = model.pair_enabled.numpy() != 0
    touched = (pairs | pairs.T)[:, free].any(axis=1)
    return ~free & ~touched


def record_start(model, state, dt: float, gravity, v_before: wp.array,
                 parallel: bool | None = None) -> tuple[Callable[[], None], Callable[[], None]]:
    """Replays writing the sweeps' first guess [n] [m/s] into ``state.sweep_buffers[0]`` and
    ``[2]`` (the buffer before it): (first step: the explicit step under ``gravity`` [3]
    [m/s^2] and ``state.external``; later steps: last step's velocity change carried on, from
    ``v_before`` [n] [m/s]: a share of it, fitted to the last steps' solves, on the free nodes
    of the :func:`shared_bodies` that are not a rigid body's, all of it on the others, so that
    every free body's guess keeps the momentum of its whole change, exact in free fall
    (:func:`_node_kernels.start_guess`, :func:`_node_kernels.share_sums`,
    :func:`_node_kernels.share_total`); ``parallel``: the fit's sums with a thread per node,
    :func:`_node_kernels.share_sums_parallel`; None: on any device but the CPU). Both then copy
    ``state.v`` into ``v_before``; on the first step a rigid body's nodes (``model.rigid``) start at its unconstrained velocity,
    later ones carried on as the others': a tool pressed into tissue by its coupling starts
    ~0.2 m/s into the tissue at its unconstrained velocity, and the sweeps' first exact update
    of the shoulder's inner finger then spun it at 18 rad/s, which took ~60 sweeps to settle
    (steps 71-120 of shoulder.toml: 63 -> 33 sweeps a step carried on)."""
    d = model.device
    for kernel in (_k.start_guess, _k.share_sums, _k.share_total):
        load_kernels(kernel, d)
    buf = state.sweep_buffers
    r = model.rigid
    start = np.asarray(model.body_node_start)
    fitted = (model.fixed.numpy() == 0) & np.repeat(shared_bodies(model), np.diff(start))
    if r is not None:
        fitted[r.linear_node.numpy()] = False
        fitted[r.angular_node.numpy()] = False
    fitted_nodes: wp.array = wp.array(fitted.astype(np.int32), dtype=wp.int32, device=d)
    share: wp.array = wp.array([0.0, 0.0, 1.0], dtype=wp.float64, device=d)
    change = wp.zeros(model.node_count, dtype=wp.vec3d, device=d)
    sums = wp.zeros(len(start) - 1, dtype=wp.vec2d, device=d)
    replays = []
    for carried in (0, 1):
        launches = []
        if carried and ((not wp.get_device(d).is_cpu) if parallel is None else parallel):
            node_body = np.repeat(np.arange(len(start) - 1, dtype=np.int32), np.diff(start))
            load_kernels(_k.share_sums_parallel, d)
            launches += [sums.zero_, replayer(wp.launch(
                _k.share_sums_parallel, dim=model.node_count, device=d, record_cmd=True,
                inputs=[wp.array(node_body, dtype=wp.int32, device=d), state.v, v_before, change, model.mass,
                        fitted_nodes, sums]))]
        elif carried:
            launches.append(replayer(wp.launch(_k.share_sums, dim=len(start) - 1, device=d, record_cmd=True,
                                               inputs=[wp.array(start, dtype=wp.int32, device=d), state.v, v_before,
                                                       change, model.mass, fitted_nodes, sums])))
        launches += [replayer(wp.launch(_k.share_total, dim=1, device=d, record_cmd=True,
                                        inputs=[sums, SHARE_MEMORY, carried, share])),
                     replayer(wp.launch(_k.start_guess, dim=model.node_count, device=d, record_cmd=True,
                                        inputs=[state.v, state.external, model.mass,
                                                wp.vec3d(*np.asarray(gravity, float)), float(dt), carried,
                                                model.fixed, state.fixed_velocity, v_before, fitted_nodes, share,
                                                change, buf[0], buf[2]]))]
        if r is not None and not carried:
            load_kernels(_k.rigid_start_guess, d)
            launches.append(replayer(wp.launch(_k.rigid_start_guess, dim=len(r.bodies), device=d, record_cmd=True,
                                               inputs=[r.linear_node, r.angular_node, r.state.free_velocity, buf[0],
                                                       buf[2]])))
        replays.append(in_order(*launches))
    return replays[0], replays[1]


def record_integrate(model, state, dt: float, solved: wp.array) -> wp.Launch:
    """The launch moving every node by the solved velocity ``solved`` [n] [m/s] over ``dt`` [s]
    into ``state.q`` / ``state.v``; a node past its limits is flagged in ``state.diverged``."""
    load_kernels(_k.integrate, model.device)
    return wp.launch(_k.integrate, dim=model.node_count, device=model.device, record_cmd=True,
                     inputs=[solved, model.speed_limit, float(dt), state.q, state.v, state.diverged])
