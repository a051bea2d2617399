"""Couplings (thesis 5.3.2, eq. 5.4) on the whole-scene node arrays: the springs' extra blocks
of ``A`` and their forces in ``b``, as recorded launches replayed every step after the element
assembly and the rigid bodies' system (:mod:`softvr.dynamics.node_arrays`,
:mod:`softvr.dynamics.node_rigid`); kernels in :mod:`softvr.dynamics._node_coupling_kernels`.
Works on :class:`softvr.sim.NodeModel` / :class:`softvr.sim.NodeState` and the model's
``couplings`` (``NodeModel.couplings``: the springs' stencils, signed weights, rigid sides,
stiffness, and the blocks and nodes they add to), or any objects with those attributes.
"""

from __future__ import annotations

from collections.abc import Callable

import warp as wp

from softvr.device import blocked_replayer, load_kernels, replayer
from softvr.dynamics import _node_coupling_kernels as _k

__all__ = ["SPRING_STENCIL", "record_couplings"]

#: Nodes in a spring's joined stencil (side a's up to 4, then side b's).
SPRING_STENCIL = int(_k.SPRING_STENCIL)


def record_couplings(model, state, dt: float) -> tuple[Callable[[], None], ...]:
    """Replays (to run in order) adding the couplings' terms of a step of ``dt`` [s] to ``A`` (``state.blocks``,
    ``state.d_inv``) and ``b`` (``state.b``), from ``state.q`` and the rigid bodies' poses at the
    step's start, and inverting each spring-held rigid body's 6x6 block of ``D_A`` (``state.d_inv``,
    ``couplings.cross``); replay after the assembly, the right-hand side and the rigid bodies' system."""
    c, d = model.couplings, model.device
    for kernel in (_k.coupling_stretch, _k.coupling_blocks, _k.coupling_forces, _k.pair_inverse):
        load_kernels(kernel, d)
    if model.rigid is not None:
        position, orientation = model.rigid.state.body_position, model.rigid.state.body_orientation
    else:
        position, orientation = wp.zeros(1, dtype=wp.vec3d, device=d), wp.zeros(1, dtype=wp.vec4d, device=d)
    # A thread per spring, block or node costs a call of the compiled kernel, more than the
    # item's few products (656 blocks on the shoulder): several items a CPU thread
    # (device.ITEMS_A_CPU_THREAD).
    replays = [blocked_replayer(_k.coupling_stretch, c.spring_count,
                                [c.nodes, c.weights, c.rigid, c.local, state.q, position, orientation, c.lever,
                                 c.stretch], d),
               blocked_replayer(_k.coupling_blocks, c.block.shape[0],
                                [c.block, c.block_rigid, c.block_entry_start, c.block_entry, c.weights, c.rigid,
                                 c.lever, c.stiffness, c.damping, model.block_row, model.block_col, float(dt),
                                 state.blocks, state.d_inv], d),
               blocked_replayer(_k.coupling_forces, c.node.shape[0],
                                [c.node, c.entry_start, c.entry, c.weights, c.rigid, c.lever, c.stiffness,
                                 c.stretch, float(dt), state.b], d)]
    if c.pair_node.shape[0]:  # spring-held rigid bodies (Warp records no launch of 0 threads)
        replays.append(replayer(wp.launch(_k.pair_inverse, dim=c.pair_node.shape[0], device=d, record_cmd=True,
                                          inputs=[c.pair_node, c.pair_block, state.blocks, state.d_inv, c.cross])))
    return tuple(replays)
