"""Compiled per-node work of the FEM bodies of a whole scene: the step matrix of thesis eq. 5.2
in node blocks, its right-hand side, and the integration.

    A = M (1 + dt alpha) + (dt beta + dt^2) K,   K = sum_e R_e K_e R_e^T   (3x3 blocks, BSR)
    b = M v0 + dt (f_elastic + M g + f_external)
    q1 = q0 + dt v1

Each block of ``A`` gathers R_e K_e,ab R_e^T of its tets and each node its element forces
through a precomputed list (one thread per block or node, no atomics: the sum is the same on
every device and in every run); R_e is the polar rotation of :mod:`._fem_kernels`.
"""

from __future__ import annotations

import warp as wp

from softvr.dynamics._fem_kernels import element_local, warm_element_rotation

#: ``NodeState.diverged`` codes.
NAN_VELOCITY = wp.constant(1)
TOO_FAST = wp.constant(2)


@wp.func
def _turn(q: wp.array(dtype=wp.vec3d), tets: wp.array2d(dtype=wp.int32), dm_inv: wp.array(dtype=wp.mat33d), e: int,
          corotational: int, keep: wp.float64, rotations: wp.array(dtype=wp.mat33d),
          turned: wp.array(dtype=wp.int32)) -> wp.mat33d:
    """Tet ``e``'s R_e from the one it replaces (:func:`warm_element_rotation`), stored, and
    whether it changed at all into ``turned[e]`` (1, else 0: its blocks of ``A`` stay)."""
    old = rotations[e]
    r = warm_element_rotation(q, tets, dm_inv, e, corotational, rotations, keep)
    d = r - old
    turned[e] = wp.where(wp.ddot(d, d) > wp.float64(0.0), 1, 0)
    rotations[e] = r
    return r


@wp.func
def _held(holding: int, q: wp.array(dtype=wp.vec3d), tets: wp.array2d(dtype=wp.int32), e: int,
          hold: wp.array(dtype=wp.float64), held: wp.array2d(dtype=wp.vec3d),
          turned: wp.array(dtype=wp.int32)) -> bool:
    """Whether tet ``e``'s terms are held (``holding``, and each of its nodes within ``hold[e]``
    [m] of where they were last computed, ``held[e]`` [4] [m]; then ``turned[e]`` = 0); if not
    (and ``holding``), ``held[e]`` takes the nodes' positions."""
    if holding == 0:
        return False
    reach = hold[e] * hold[e]
    far = wp.float64(0.0)
    for a in range(4):
        d = q[tets[e, a]] - held[e, a]
        far = wp.max(far, wp.dot(d, d))
    if far <= reach:
        turned[e] = 0
        return True
    for a in range(4):
        held[e, a] = q[tets[e, a]]
    return False


@wp.kernel
def element_terms(q: wp.array(dtype=wp.vec3d), rest: wp.array(dtype=wp.vec3d), tets: wp.array2d(dtype=wp.int32),
                  dm_inv: wp.array(dtype=wp.mat33d), ke: wp.array2d(dtype=wp.mat33d), corotational: int,
                  live: wp.array(dtype=wp.int32), keep: wp.float64, holding: int, hold: wp.array(dtype=wp.float64),
                  held: wp.array2d(dtype=wp.vec3d), rotations: wp.array(dtype=wp.mat33d),
                  turned: wp.array(dtype=wp.int32), forces: wp.array2d(dtype=wp.vec3d), block: int, offset: int):
    """R_e (last step's where within ``keep`` [rad] of the polar rotation:
    :func:`_fem_kernels.lagged_polar_rotation`; ``turned[e]`` 1 where R_e changed, else 0) and
    the elastic forces f_e,a = -R_e sum_b K_e,ab (R_e^T x_b - X_b) [N] of tets ``e =
    live[i]`` (``ke[e, 4 a + b]`` the 3x3 blocks of K_e, rest frame [N/m]); a thread takes
    ``block`` of the ``i``, from (thread + ``offset``) x ``block``
    (:func:`softvr.device.blocked_replayer`). With ``holding``, a tet whose nodes are all within
    ``hold[e]`` [m] of where its terms were last computed (``held``, :func:`_held`) keeps them
    as they are."""
    begin = (wp.tid() + offset) * block
    for i in range(begin, wp.min(begin + block, live.shape[0])):
        e = live[i]
        if _held(holding, q, tets, e, hold, held, turned):
            continue
        r = _turn(q, tets, dm_inv, e, corotational, keep, rotations, turned)
        local0, local1, local2, local3 = element_local(q, rest, tets, e, wp.transpose(r))
        for a in range(4):
            fa = ke[e, 4 * a] * local0 + ke[e, 4 * a + 1] * local1 + ke[e, 4 * a + 2] * local2 + \
                ke[e, 4 * a + 3] * local3
            forces[e, a] = -(r * fa)


@wp.kernel
def element_terms_isotropic(q: wp.array(dtype=wp.vec3d), rest: wp.array(dtype=wp.vec3d),
                            tets: wp.array2d(dtype=wp.int32), dm_inv: wp.array(dtype=wp.mat33d),
                            gradients: wp.array2d(dtype=wp.vec3d), lame: wp.array(dtype=wp.vec2d), corotational: int,
                            live: wp.array(dtype=wp.int32), keep: wp.float64, holding: int,
                            hold: wp.array(dtype=wp.float64), held: wp.array2d(dtype=wp.vec3d),
                            rotations: wp.array(dtype=wp.mat33d), turned: wp.array(dtype=wp.int32),
                            forces: wp.array2d(dtype=wp.vec3d), rotated_gradients: wp.array2d(dtype=wp.vec3d),
                            block: int, offset: int):
    """:func:`element_terms` for isotropic linear tets (``gradients[e, a]`` = g_a [1/m],
    ``lame[e]`` = V (lambda, mu) [N/m], as :func:`assemble_isotropic`): with the rotated
    frame's displacement gradient H = sum_b (R^T x_b - X_b) g_b^T,

        sum_b K_e,ab (R^T x_b - X_b) = V (lambda tr(H) I + mu (H + H^T)) g_a

    (Hooke's stress of the small strain, times the area vector), so f_e,a = -R V sigma g_a [N]:
    four outer products and four matrix-vector products a tet, not sixteen 3x3 blocks read and
    applied. Equal to :func:`element_terms`'s sum in exact arithmetic; both round each term
    at ~u |K_e| |R^T x - X| (u = 1.1e-16). Also writes R g_a [1/m] for
    :func:`assemble_isotropic` where R_e turned. ``keep``, ``holding``, ``hold``, ``held``,
    ``turned``: :func:`element_terms`'."""
    begin = (wp.tid() + offset) * block
    for i in range(begin, wp.min(begin + block, live.shape[0])):
        e = live[i]
        if _held(holding, q, tets, e, hold, held, turned):
            continue
        r = _turn(q, tets, dm_inv, e, corotational, keep, rotations, turned)
        local0, local1, local2, local3 = element_local(q, rest, tets, e, wp.transpose(r))
        g0 = gradients[e, 0]
        g1 = gradients[e, 1]
        g2 = gradients[e, 2]
        g3 = gradients[e, 3]
        h = wp.outer(local0, g0) + wp.outer(local1, g1) + wp.outer(local2, g2) + wp.outer(local3, g3)
        l = lame[e]
        trace = l[0] * (h[0, 0] + h[1, 1] + h[2, 2])
        zero = wp.float64(0.0)
        stress = l[1] * (h + wp.transpose(h)) + wp.mat33d(trace, zero, zero, zero, trace, zero, zero, zero, trace)
        rs = r * stress
        forces[e, 0] = -(rs * g0)
        forces[e, 1] = -(rs * g1)
        forces[e, 2] = -(rs * g2)
        forces[e, 3] = -(rs * g3)
        if turned[e] != 0:
            rotated_gradients[e, 0] = r * g0
            rotated_gradients[e, 1] = r * g1
            rotated_gradients[e, 2] = r * g2
            rotated_gradients[e, 3] = r * g3


@wp.func
def store_block(k: int, m: wp.mat33d, block_row: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                block_mirror: wp.array(dtype=wp.int32), mass: wp.array(dtype=wp.float64),
                node_alpha: wp.array(dtype=wp.float64), dt: wp.float64, blocks: wp.array(dtype=wp.mat33d),
                d_inv: wp.array(dtype=wp.mat33d)):
    """Block ``k`` of ``A`` [kg] from its stiffness sum ``m`` [kg]: plus M (1 + dt alpha) on
    the diagonal, where it also writes ``D_A^-1`` [1/kg], and transposed at ``block_mirror[k]``
    (K_e is symmetric, so block (b, a) is block (a, b) transposed: the off-diagonal half is
    not summed twice)."""
    i = block_row[k]
    if block_col[k] == i:
        md = mass[i] * (wp.float64(1.0) + dt * node_alpha[i])
        m = m + wp.mat33d(md, wp.float64(0.0), wp.float64(0.0), wp.float64(0.0), md, wp.float64(0.0),
                          wp.float64(0.0), wp.float64(0.0), md)
        d_inv[i] = wp.inverse(m)
    blocks[k] = m
    t = block_mirror[k]
    if t >= 0 and t != k:
        blocks[t] = wp.transpose(m)


@wp.func_native(r"""
if (lagging == 0) return false;
const int* code = (const int*)contrib.data;
const int* flag = (const int*)turned.data;
for (int c = ((const int*)contrib_start.data)[k], end = ((const int*)contrib_start.data)[k + 1]; c < end; ++c)
    if (flag[code[c] / 16] != 0) return false;
return true;
""")
def _kept(k: int, contrib_start: wp.array(dtype=wp.int32), contrib: wp.array(dtype=wp.int32),
          turned: wp.array(dtype=wp.int32), lagging: int) -> bool:
    """Whether block ``k`` of ``A`` keeps last step's value: ``lagging`` and none of its tets'
    R_e changed (the same rotations sum to the same bits, and nothing else writes ``A``). In
    C++ (contiguous arrays): most blocks are kept, and Warp's loop over their tets' flags cost
    ~19 ns a block, as much as assembling a sixth of them."""
    ...


@wp.kernel
def assemble(assembled: wp.array(dtype=wp.int32), block_mirror: wp.array(dtype=wp.int32),
             block_row: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
             contrib_start: wp.array(dtype=wp.int32), contrib: wp.array(dtype=wp.int32),
             rotations: wp.array(dtype=wp.mat33d), ke: wp.array2d(dtype=wp.mat33d),
             tet_beta: wp.array(dtype=wp.float64), mass: wp.array(dtype=wp.float64),
             node_alpha: wp.array(dtype=wp.float64), dt: wp.float64, turned: wp.array(dtype=wp.int32), lagging: int,
             blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d), block: int, offset: int):
    """Blocks ``k = assembled[i]`` of ``A`` [kg] and their transposes (:func:`store_block`), any
    element stiffness ``ke`` [N/m]; a thread takes ``block`` of the ``i``, from (thread +
    ``offset``) x ``block`` (:func:`softvr.device.blocked_replayer`). ``contrib[c]`` = 16 tet + 4 a + b: R_e K_e,ab R_e^T of that
    tet adds to block ``k``. With ``lagging``, a block none of whose tets turned (``turned``)
    is left as it is (:func:`_kept`)."""
    begin = (wp.tid() + offset) * block
    for i in range(begin, wp.min(begin + block, assembled.shape[0])):
        k = assembled[i]
        if _kept(k, contrib_start, contrib, turned, lagging):
            continue
        m = wp.mat33d()
        for c in range(contrib_start[k], contrib_start[k + 1]):
            code = contrib[c]
            e = code // 16
            r = rotations[e]
            m = m + (dt * tet_beta[e] + dt * dt) * (r * ke[e, code % 16] * wp.transpose(r))
        store_block(k, m, block_row, block_col, block_mirror, mass, node_alpha, dt, blocks, d_inv)


# _isotropic_sum: a block's isotropic contributions as plain C++, the same wp:: operations in the
# same order as Warp's loop would take them, ``m + l0 (R g_a)(R g_b)^T + l1 (R g_b)(R g_a)^T``
# and the diagonal's ``l1 (R g_a . R g_b)`` (so the same bits), with none of its per-access index
# arithmetic: the candy's assembly 1.44 -> 1.13 ms on one core. It reads the arrays as contiguous.
_ISOTROPIC_SUM = r"""
typedef wp::vec_t<3, wp::float64> vec3;
typedef wp::mat_t<3, 3, wp::float64> mat3;
const int per_tet = rotated_gradients.shape[1];
const vec3* gradient = (const vec3*)rotated_gradients.data;
const wp::vec_t<2, wp::float64>* moduli = (const wp::vec_t<2, wp::float64>*)lame.data;
mat3 m = mat3();
wp::float64 diagonal = 0.0;
for (int c = contrib_start.data[k], end = contrib_start.data[k + 1]; c < end; ++c) {
    const int code = contrib.data[c];
    const int e = code / 16;
    const vec3 ra = gradient[e * per_tet + (code / 4) % 4];
    const vec3 rb = gradient[e * per_tet + code % 4];
    const wp::vec_t<2, wp::float64> l = moduli[e];
    m = wp::add(wp::add(m, wp::mul(l[0], wp::outer(ra, rb))), wp::mul(l[1], wp::outer(rb, ra)));
    diagonal = wp::add(diagonal, wp::mul(l[1], wp::dot(ra, rb)));
}
return wp::add(m, mat3(diagonal, 0.0, 0.0, 0.0, diagonal, 0.0, 0.0, 0.0, diagonal));
"""


@wp.func_native(_ISOTROPIC_SUM)
def _isotropic_sum(k: int, contrib_start: wp.array(dtype=wp.int32), contrib: wp.array(dtype=wp.int32),
                   rotated_gradients: wp.array2d(dtype=wp.vec3d), lame: wp.array(dtype=wp.vec2d)) -> wp.mat33d:
    """Block ``k``'s sum of ``R K_e,ab R^T`` [kg] over its contributions (``contrib[c]`` = 16 tet
    + 4 a + b, ``c`` in ``contrib_start[k]:contrib_start[k + 1]``) with the diagonal term added
    (:func:`assemble_isotropic`; :data:`_ISOTROPIC_SUM`)."""
    ...


@wp.kernel
def assemble_isotropic(assembled: wp.array(dtype=wp.int32), block_mirror: wp.array(dtype=wp.int32),
                       block_row: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                       contrib_start: wp.array(dtype=wp.int32), contrib: wp.array(dtype=wp.int32),
                       rotated_gradients: wp.array2d(dtype=wp.vec3d), lame: wp.array(dtype=wp.vec2d),
                       mass: wp.array(dtype=wp.float64), node_alpha: wp.array(dtype=wp.float64), dt: wp.float64,
                       turned: wp.array(dtype=wp.int32), lagging: int, blocks: wp.array(dtype=wp.mat33d),
                       d_inv: wp.array(dtype=wp.mat33d), block: int, offset: int):
    """:func:`assemble` for isotropic linear tets, K_e,ab = V (lambda g_a g_b^T + mu g_b g_a^T
    + mu (g_a . g_b) I) (K_e = V B^T C B with isotropic C, g_a [1/m] the shape functions' rest
    gradients; ``rotated_gradients[e, a]`` = R g_a, of :func:`element_terms_isotropic`;
    ``lame[e]`` = (dt beta + dt^2) V (lambda, mu) [N s^2/m]):

        R K_e,ab R^T = V (lambda (R g_a)(R g_b)^T + mu (R g_b)(R g_a)^T + mu (R g_a . R g_b) I)

    two outer products a contribution, not two 3x3 products (~5x fewer flops). Exact for an
    orthogonal R; with |R^T R - I| = eps_R (the polar iteration stops at round-off, ~1e-15) and
    float64 rounding u, a contribution differs from :func:`assemble`'s by at most
    ~(eps_R + 20 u) |K_e| (both are R K R^T up to those terms). ``turned``, ``lagging``, ``block`` as
    :func:`assemble`'s."""
    begin = (wp.tid() + offset) * block
    for i in range(begin, wp.min(begin + block, assembled.shape[0])):
        k = assembled[i]
        if _kept(k, contrib_start, contrib, turned, lagging):
            continue
        m = _isotropic_sum(k, contrib_start, contrib, rotated_gradients, lame)
        store_block(k, m, block_row, block_col, block_mirror, mass, node_alpha, dt, blocks, d_inv)


@wp.kernel
def right_hand_side(force_start: wp.array(dtype=wp.int32), force: wp.array(dtype=wp.int32),
                    forces: wp.array2d(dtype=wp.vec3d), mass: wp.array(dtype=wp.float64),
                    v: wp.array(dtype=wp.vec3d), external: wp.array(dtype=wp.vec3d), gravity: wp.vec3d,
                    dt: wp.float64, b: wp.array(dtype=wp.vec3d)):
    """``b`` [kg m/s] of node ``i``; ``force[c]`` = 4 tet + a: node a of the tet is node ``i``."""
    i = wp.tid()
    f = wp.vec3d()
    for c in range(force_start[i], force_start[i + 1]):
        f = f + forces[force[c] // 4, force[c] % 4]
    b[i] = mass[i] * v[i] + dt * (f + mass[i] * gravity + external[i])


@wp.kernel
def integrate(v_new: wp.array(dtype=wp.vec3d), speed_limit: wp.array(dtype=wp.float64), dt: wp.float64,
              q: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d), diverged: wp.array(dtype=wp.int32)):
    """``q += dt v1``, ``v = v1``; a node whose velocity is not finite or faster than its body's
    limit [m/s] (a thousand body sizes per second: it has blown up) is flagged and not moved."""
    i = wp.tid()
    vi = v_new[i]
    speed = wp.length(vi)
    if not (wp.isfinite(vi[0]) and wp.isfinite(vi[1]) and wp.isfinite(vi[2])):
        diverged[i] = NAN_VELOCITY
        return
    if speed > speed_limit[i]:
        diverged[i] = TOO_FAST
        return
    v[i] = vi
    q[i] = q[i] + dt * vi


@wp.kernel
def start_guess(v: wp.array(dtype=wp.vec3d), external: wp.array(dtype=wp.vec3d), mass: wp.array(dtype=wp.float64),
                gravity: wp.vec3d, dt: wp.float64, carried: int, fixed: wp.array(dtype=wp.int32),
                fixed_velocity: wp.array(dtype=wp.vec3d), v_before: wp.array(dtype=wp.vec3d),
                fitted: wp.array(dtype=wp.int32), share: wp.array(dtype=wp.float64), change: wp.array(dtype=wp.vec3d),
                guess: wp.array(dtype=wp.vec3d), guess_prev: wp.array(dtype=wp.vec3d)):
    """The sweeps' first velocity [m/s] of node ``i``, in both buffers the first sweep reads:
    with ``carried``, last step's change ``c = v - v_before`` [m/s] carried on, on a ``fitted``
    [n] node a share of it, ``v + share[2] c`` (:func:`share_total`), on any other all of it,
    ``2 v - v_before``; else the explicit step ``v + dt (g + f_ext / m)``; a fixed node's fixed
    velocity. ``change`` [n] [m/s] then takes ``c`` on a fitted node (0 elsewhere and on the
    explicit step) and ``v_before`` takes ``v``. A uniform change (gravity, a push, a resting
    body's none) is Jacobi's slowest mode, and these guesses have it.

    The fitted nodes are held bodies' (:func:`softvr.dynamics.node_arrays.shared_bodies`): a
    free body's nodes carry all of ``c``, so its guessed momentum is ``sum m (2 v - v_before)
    = P + (P - P_before)``: in free fall ``P + M g dt``, the step's exact impulse (each step's
    solve has it, so its change does), whatever share is fitted. A share on a free body's
    change would leave ``(1 - share) M g dt`` out of the guess's momentum, an error in its
    uniform motion (over a body no spring ties to a fixed node ``1^T A = 1^T M``), the sweeps'
    slowest mode, most of which the stop leaves: session 13's share on every node left the
    oranges' vertical momentum 2.4e-6 of M g t off after 32 steps."""
    i = wp.tid()
    vi = v[i]
    g = vi + dt * (gravity + external[i] / mass[i])
    step = wp.vec3d()
    if carried != 0:
        g = wp.float64(2.0) * vi - v_before[i]
        if fitted[i] != 0:
            step = vi - v_before[i]
            g = vi + share[2] * step
    if fixed[i] != 0:
        g = fixed_velocity[i]
    guess[i] = g
    guess_prev[i] = g
    change[i] = step
    v_before[i] = vi


@wp.kernel
def share_sums(body_node_start: wp.array(dtype=wp.int32), v: wp.array(dtype=wp.vec3d),
               v_before: wp.array(dtype=wp.vec3d), change: wp.array(dtype=wp.vec3d), mass: wp.array(dtype=wp.float64),
               fitted: wp.array(dtype=wp.int32), sums: wp.array(dtype=wp.vec2d)):
    """Body ``b``'s terms of the share's fit (:func:`share_total`) over its ``fitted`` nodes
    (``body_node_start[b]:body_node_start[b + 1]``): ``sums[b]`` = (``sum m r . change``,
    ``sum m |change|^2``) [kg m^2/s^2] of the change the last solve made, ``r = v - v_before``
    [m/s], and the change carried into it, ``change`` [m/s] (:func:`start_guess`). One thread
    a body, its nodes in order: the same sums in every run, on every device."""
    b = wp.tid()
    num = wp.float64(0.0)
    den = wp.float64(0.0)
    for i in range(body_node_start[b], body_node_start[b + 1]):
        if fitted[i] != 0:
            c = change[i]
            num = num + mass[i] * wp.dot(v[i] - v_before[i], c)
            den = den + mass[i] * wp.dot(c, c)
    sums[b] = wp.vec2d(num, den)


@wp.kernel
def share_sums_parallel(node_body: wp.array(dtype=wp.int32), v: wp.array(dtype=wp.vec3d),
                        v_before: wp.array(dtype=wp.vec3d), change: wp.array(dtype=wp.vec3d),
                        mass: wp.array(dtype=wp.float64), fitted: wp.array(dtype=wp.int32),
                        sums: wp.array(dtype=wp.vec2d)):
    """:func:`share_sums` with a thread per node ``i`` (a GPU's form), added into its body
    ``node_body[i]``'s ``sums`` (zeroed before) atomically: on CUDA in no fixed order."""
    i = wp.tid()
    if fitted[i] != 0:
        c = change[i]
        wp.atomic_add(sums, node_body[i], wp.vec2d(mass[i] * wp.dot(v[i] - v_before[i], c), mass[i] * wp.dot(c, c)))


@wp.kernel
def share_total(sums: wp.array(dtype=wp.vec2d), memory: wp.float64, carried: int,
                share: wp.array(dtype=wp.float64)):
    """The share of last step's change that the next first guess carries on at the fitted nodes
    (:func:`start_guess`): the mass-weighted least-squares coefficient of the change each solve
    made on the change carried into it, ``share[2] = sum_s mu^(t-s) num_s / sum_s mu^(t-s)
    den_s``, this step's ``(num, den)`` the bodies' ``sums`` [B] (:func:`share_sums`) added in
    body order, the older steps' kept in ``share[0]``, ``share[1]`` weighed down by ``memory``
    (mu) a step, clipped to [0, 1]; 1 (all of it) until a step has been carried into, and after
    the explicit step (``carried`` 0: the sums start again). One thread."""
    if carried == 0:
        share[0] = wp.float64(0.0)
        share[1] = wp.float64(0.0)
        share[2] = wp.float64(1.0)
        return
    total = wp.vec2d()
    for b in range(sums.shape[0]):
        total = total + sums[b]
    num = memory * share[0] + total[0]
    den = memory * share[1] + total[1]
    share[0] = num
    share[1] = den
    a = wp.float64(1.0)
    if den > wp.float64(0.0):
        a = wp.clamp(num / den, wp.float64(0.0), wp.float64(1.0))
    share[2] = a


@wp.kernel
def rigid_start_guess(linear_node: wp.array(dtype=wp.int32), angular_node: wp.array(dtype=wp.int32),
                      free_velocity: wp.array(dtype=wp.spatial_vectord), guess: wp.array(dtype=wp.vec3d),
                      guess_prev: wp.array(dtype=wp.vec3d)):
    """The sweeps' first velocity at rigid body ``r``'s two nodes: its unconstrained velocity
    [m/s, rad/s] (eq. 5.2), which a sweep without contacts returns."""
    r = wp.tid()
    f = free_velocity[r]
    guess[linear_node[r]] = wp.spatial_top(f)
    guess_prev[linear_node[r]] = wp.spatial_top(f)
    guess[angular_node[r]] = wp.spatial_bottom(f)
    guess_prev[angular_node[r]] = wp.spatial_bottom(f)


@wp.kernel
def drive(drive_node: wp.array(dtype=wp.int32), drive_body: wp.array(dtype=wp.int32),
          drive_local: wp.array(dtype=wp.vec3d), position: wp.array(dtype=wp.vec3d),
          rotation: wp.array(dtype=wp.mat33d), velocity: wp.array(dtype=wp.spatial_vectord),
          q: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d), fixed_velocity: wp.array(dtype=wp.vec3d)):
    """Driven node ``drive_node[k]`` where its point of a kinematic or fixed body is, ``c + R r``
    [m], and how it moves over the step, ``v + w x R r`` [m/s] (its fixed velocity)."""
    k = wp.tid()
    i = drive_node[k]
    b = drive_body[k]
    r = rotation[b] * drive_local[k]
    u = velocity[b]
    w = wp.spatial_top(u) + wp.cross(wp.spatial_bottom(u), r)
    q[i] = position[b] + r
    fixed_velocity[i] = w
    v[i] = w
