"""Couplings (thesis 5.3.2, eq. 5.4) on the whole-scene node arrays: the springs' extra blocks
of ``A`` and their forces in ``b``, as recorded launches replayed every step after the element
assembly (:mod:`softvr.dynamics.node_arrays`); kernels in
:mod:`softvr.dynamics._node_coupling_kernels`. Works on :class:`softvr.sim.NodeModel` /
:class:`softvr.sim.NodeState` and the model's ``couplings`` (``NodeModel.couplings``: the springs'
stencils, signed weights, stiffness, and the blocks and nodes they add to), or any objects with
those attributes.
"""

from __future__ import annotations

from collections.abc import Callable

import warp as wp

from softvr.device import load_kernels, replayer
from softvr.dynamics import _node_coupling_kernels as _k

__all__ = ["SPRING_STENCIL", "record_couplings"]

#: Nodes in a spring's joined stencil (side a's up to 4, then side b's).
SPRING_STENCIL = int(_k.SPRING_STENCIL)


def record_couplings(model, state, dt: float) -> tuple[Callable[[], None], Callable[[], None]]:
    """Replays adding the couplings' terms of a step of ``dt`` [s]: to ``A`` (``state.blocks``,
    ``state.d_inv``; replay after the assembly) and to ``b`` (``state.b``, from ``state.q`` at
    the step's start; replay after the right-hand side)."""
    c, d = model.couplings, model.device
    for kernel in (_k.coupling_blocks, _k.coupling_forces):
        load_kernels(kernel, d)
    blocks = wp.launch(_k.coupling_blocks, dim=c.block.shape[0], device=d, record_cmd=True,
                       inputs=[c.block, c.block_stiffness, c.block_damping, model.block_row, model.block_col,
                               float(dt), state.blocks, state.d_inv])
    forces = wp.launch(_k.coupling_forces, dim=c.node.shape[0], device=d, record_cmd=True,
                       inputs=[c.node, c.entry_start, c.entry, c.nodes, c.weights, c.stiffness, state.q, float(dt),
                               state.b])
    return replayer(blocks), replayer(forces)
