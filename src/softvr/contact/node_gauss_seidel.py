"""Multicolour symmetric block Gauss-Seidel sweeps for the node solve of thesis eq. 5.6 (in
place of its outer Jacobi; kernels and the derivation in
:mod:`softvr.contact._node_gs_kernels`): the recorded launches of one sweep's node update and
the spectrum of the iteration that the Chebyshev weights need. On a stiff, heterogeneous body
the symmetric Gauss-Seidel iteration's condition number is about the square root of node-block
Jacobi's (head CT: 239 against 1 707), so it needs ~2.7x fewer sweeps at ~2x the node work.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

from softvr.collision.node_rigid_detection import CONTACT_THREADS
from softvr.contact import _node_block_kernels as _bk
from softvr.contact import _node_gs_kernels as _k
from softvr.contact._node_block_kernels import CONTACT_BLOCK_THREADS
from softvr.contact.node_coarse import Aggregates
from softvr.contact.node_colouring import NodeColouring
from softvr.contact.node_gs_coarse import GaussSeidelCoarse
from softvr.device import chunked_replayer, cpu_workers, in_order, replayer, stride_threads, upload
from softvr.dynamics.node_rigid import isolated_rigid_nodes, rigid_islands

__all__ = ["COLOUR_CHUNK", "ISLAND_NODES", "SLEEP_GAP_SHARE", "TOOL_PASSES", "GaussSeidelSweep", "free_first",
           "gauss_seidel_spectrum", "off_diagonal_rows"]

#: A contact without impulse or adhesion sleeps through a step's sweeps (its nodes take the
#: Gauss-Seidel update, not the contact nodes' damped Jacobi one) while its normal velocity at
#: the step's start closes at most this share of its gap over the step
#: (:mod:`softvr.contact._node_gs_kernels`).
SLEEP_GAP_SHARE = 0.5
#: Nodes of the largest rigid island (two per body) a sweep solves whole, its block of ``A`` a
#: dense inverse made once a step (:func:`softvr.contact._node_gs_kernels.island_solve`).
ISLAND_NODES = 8
#: Extra PGS passes a sweep over the contacts of the rigid bodies whose update is exact (a
#: held tool, a rigid island): their impulses all act on the body's 6 (or the island's) dofs,
#: so one pass's updates undo each other's, and the tool's wrench settles over passes, not
#: sweeps. Measured (`diag.py`, 60 / 70 steps, in-contact steps): the same sweeps as 10
#: passes over every contact; palpation steps 39-59 ~95 -> ~73 sweeps with the exact update.
TOOL_PASSES = 8
#: A colour's launch is split over the CPU cores from twice this many nodes
#: (:func:`softvr.device.chunked_replayer`'s ``min_chunk``).
COLOUR_CHUNK = 1024

#: Nodes per lane of one block (:data:`CONTACT_BLOCK_THREADS` lanes) up to which a sweep in the
#: GPU's form (``parallel``) runs as two block launches around its contact step, a barrier
#: where the launches' form ends a launch (each colour, the islands, the contact nodes): the
#: shoulder's 1 247 nodes, ~200 a colour, in 2 launches a sweep instead of ~27. A larger body
#: keeps a launch a colour over the whole device (not measured on a GPU yet).
BLOCK_NODES_PER_LANE = 8


class GaussSeidelSweep:
    """The recorded node update of one symmetric sweep (steps 1-4 of
    :mod:`softvr.contact._node_gs_kernels`) from the velocities ``v`` [n] [m/s] into
    ``state.v_hat``, with the contact PGS ``contacts`` (a replay of the shared contact kernel
    on ``state.v_hat`` with the metric :attr:`metric`) in its middle; each launch split over
    the CPU cores. :meth:`prepare` marks this step's contact nodes (those of the contacts
    that do not sleep) and sets the metric; :meth:`wake` marks the rest when one is needed.

    Parameters
    ----------
    model, state
        :class:`softvr.sim.NodeModel`, :class:`softvr.sim.NodeState`.
    colouring : NodeColouring
    omega : float
        Damping of the contact nodes' Jacobi update, at most 1 / lambda_max(D_A^-1 A).
    dt : float, optional
        The step [s] (a contact sleeps by how much of its gap it closes in it); None: no
        contact sleeps.
    coarse : Aggregates, optional
        Aggregates whose rigid motions each sweep corrects after its node update
        (:mod:`softvr.contact.node_gs_coarse`); None: none.
    parallel : bool
        The woken test and the rigid islands' contact response with a thread per contact / island
        node / island, and the colours' updates with a thread per node (a GPU's form), instead
        of one thread walking them.
    """

    def __init__(self, model, state, colouring: NodeColouring, omega: float, dt: float | None = None,
                 coarse: Aggregates | None = None, parallel: bool = False):
        d = model.device
        #: Whether the walks over a step's contacts (the woken test, the islands' contact forces)
        #: take a thread per contact (a GPU's form, ``*_parallel`` kernels) instead of one thread.
        self.parallel = bool(parallel)
        n = model.node_count
        self.omega = float(omega)
        order, free_end = free_first(colouring, model.fixed.numpy() != 0)
        self._order: wp.array = wp.array(order, dtype=wp.int32, device=d)
        self._free_end: wp.array = wp.array(free_end, dtype=wp.int32, device=d)
        self.contact_node = wp.zeros(n, dtype=wp.int32, device=d)
        #: omega D_A^-1 [n] [1/kg], the metric the contact PGS projects with.
        self.metric = wp.zeros(n, dtype=wp.mat33d, device=d)
        #: omega times the off-diagonal blocks of spring-held rigid bodies' 6x6 D_A^-1 [n].
        self.cross_metric = wp.zeros(n, dtype=wp.mat33d, device=d)
        self._work = wp.zeros(n, dtype=wp.vec3d, device=d)
        self._model, self._state = model, state
        islands = [i for i in rigid_islands(model) if 2 < len(i) <= ISLAND_NODES]
        #: The nodes [n] bool of the rigid islands each sweep solves whole (:data:`ISLAND_NODES`).
        self.island_nodes = np.zeros(n, bool)
        for island in islands:
            self.island_nodes[island] = True
        # A rigid body whose update is exact (its block of D_A, or its island's, is all of its
        # A over the nodes solved for) is not damped: the stop reads no change of its nodes (they
        # are exact to the Chebyshev step), only its contacts' residual, so a damped update, a
        # share omega of the way to its rows' solution, stopped with its rows unsolved (a box on
        # springs pressed on a plane: 0.015 rad/s off SciPy's MLCP after 2 sweeps).
        tools = isolated_rigid_nodes(model) | self.island_nodes
        #: Each node's damping [n] of its contact-node update: 1 on exact rigid bodies, else omega.
        self.node_omega: wp.array = wp.array(np.where(tools, 1.0, self.omega), dtype=wp.float64, device=d)
        #: Extra PGS passes a sweep over the live contacts of exact rigid bodies (:attr:`tool_live`).
        self.tool_passes = TOOL_PASSES if tools.any() else 0
        #: 1 on the nodes of exact rigid bodies [n] (the tools whose contacts take the extra passes).
        self.tool_node: wp.array = wp.array(tools.astype(np.int32), dtype=wp.int32, device=d)
        #: Which live contacts have a side on an exact rigid body [c] (:meth:`mark_tools`).
        self.tool_live = wp.zeros(state.contacts.capacity, dtype=wp.int32, device=d)
        #: A sweep counter the extra passes' launch counts into (not the sweeps' own).
        self.tool_sweep = wp.zeros(1, dtype=wp.int32, device=d)
        c = state.contacts
        #: Which contacts sleep this step [c] (``_node_gs_kernels.mark_contact_nodes``).
        self.asleep = wp.zeros(c.capacity, dtype=wp.int32, device=d)
        #: [1] whether a sleeping contact took an impulse since :meth:`prepare` (``woken_launches``).
        self.flag = wp.zeros(1, dtype=wp.int32, device=d)
        self._flag_view = self.flag.numpy() if wp.get_device(d).is_cpu else None

        threads = stride_threads(d, min(c.capacity, CONTACT_THREADS))

        def mark(wake_all: int) -> Callable[[], None]:
            return replayer(wp.launch(_k.mark_contact_nodes, dim=threads, device=d, record_cmd=True,
                                      inputs=[c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights, c.frame,
                                              c.gap, c.rigid_node, c.rigid_lever, c.impulse, c.stiffness,
                                              state.sweep_buffers[0], float(dt or 0.0), SLEEP_GAP_SHARE, wake_all,
                                              self.contact_node, self.asleep, threads]))

        #: Replays marking every contact's nodes (:meth:`wake`; ``woken_launches`` sets ``flag``).
        self.wake_launches = mark(1)
        if self.parallel:
            self.woken_launches = in_order(self.flag.zero_, replayer(wp.launch(
                _k.woken_parallel, dim=threads, device=d, record_cmd=True,
                inputs=[c.count, self.asleep, c.impulse, self.flag, threads])))
        else:
            self.woken_launches = replayer(wp.launch(_k.woken, dim=1, device=d, record_cmd=True,
                                                     inputs=[c.count, self.asleep, c.impulse, self.flag]))
        self._prepare = [mark(int(dt is None)),
                         replayer(wp.launch(_k.scale, dim=n, device=d, record_cmd=True,
                                            inputs=[state.d_inv, model.couplings.cross, self.node_omega, self.metric,
                                                    self.cross_metric]))]
        self._islands: list | None = None
        if islands:
            local = np.full(n, -1)
            for island in islands:
                local[island] = np.arange(len(island))
            start = np.concatenate([[0], np.cumsum([len(i) for i in islands])])
            size = 3 * ISLAND_NODES
            self._islands = [wp.array(start, dtype=wp.int32, device=d),
                             wp.array(np.concatenate(islands), dtype=wp.int32, device=d),
                             wp.array(local, dtype=wp.int32, device=d)]
            self._island_inverse = wp.zeros((len(islands), size, size), dtype=wp.float64, device=d)
            self._island_rhs = wp.zeros((len(islands), size), dtype=wp.float64, device=d)
            self._island_force = wp.zeros(n, dtype=wp.vec3d, device=d)
            self._prepare.insert(1, replayer(wp.launch(_k.mark_islands, dim=len(islands), device=d, record_cmd=True,
                                                       inputs=self._islands[:2] + [self.contact_node])))
            self.wake_launches = in_order(self.wake_launches, self._prepare[1])
            self._prepare.append(replayer(wp.launch(
                _k.island_inverse, dim=len(islands), device=d, record_cmd=True,
                inputs=[*self._islands, model.row_start, model.block_col, state.blocks,
                        wp.zeros((len(islands), size, size), dtype=wp.float64, device=d), self._island_inverse])))
            self._prepare.append(replayer(wp.launch(
                _k.island_metric, dim=len(islands), device=d, record_cmd=True,
                inputs=[*self._islands, model.couplings.partner, self._island_inverse, self.metric, self.cross_metric])))
        self._colouring = colouring
        self._colour_start: wp.array = wp.array(colouring.start, dtype=wp.int32, device=d)
        # The colour passes read the rows in colour order: a copy of the off-diagonal blocks
        # laid out that way (gathered once a step, transposed) reads them one after the other.
        off_start, off_col, off_source = off_diagonal_rows(model.row_start.numpy(), model.block_col.numpy(),
                                                           model.couplings.partner.numpy(), order)
        self._off_start: wp.array = wp.array(off_start, dtype=wp.int32, device=d)
        self._off_col: wp.array = wp.array(off_col, dtype=wp.int32, device=d)
        # (one block more than the rows hold: the CPU's row product reads one double past the last)
        self._off_blocks = wp.zeros(len(off_source) + 1, dtype=wp.mat33d, device=d)
        if len(off_source):  # none where every node is a spring-held rigid body's
            source: wp.array = wp.array(off_source, dtype=wp.int32, device=d)
            threads = 1 if wp.get_device(d).is_cpu else len(off_source)
            self._prepare.append(replayer(wp.launch(_k.gather_off_blocks, dim=threads, device=d, record_cmd=True,
                                                    inputs=[state.blocks, source, self._off_blocks, threads])))
        # On the CPU, where no colour is split over the cores, one launch walks all colours
        # (gauss_seidel_walk): a launch costs ~0.5 us, 12 a sweep on the shoulder's 6 colours.
        self._walk = wp.get_device(d).is_cpu and not self.parallel and (
            cpu_workers() == 1 or np.diff(colouring.start).max(initial=0) < 2 * COLOUR_CHUNK)
        # There the contact nodes' updates go over a list of them, made after each marking
        # (_node_gs_kernels.list_contact_nodes), not a thread a node.
        self._listed = wp.zeros(n, dtype=wp.int32, device=d)
        self._listed_count = wp.zeros(1, dtype=wp.int32, device=d)
        self._list: Callable[[], None] = lambda: None
        if self._walk:
            self._list = replayer(wp.launch(_k.list_contact_nodes, dim=1, device=d, record_cmd=True,
                                            inputs=[self._order, self.contact_node, self._listed, self._listed_count]))
            self._prepare.append(self._list)
            self.wake_launches = in_order(self.wake_launches, self._list)

        #: The coarse correction after each sweep (None: none).
        self.coarse = GaussSeidelCoarse(model, state, coarse, self.contact_node) if coarse is not None and len(
            coarse) else None
        if self.coarse is not None:  # over the step's contact nodes, marked above
            self._prepare.append(self.coarse.prepare)

    def prepare(self) -> None:
        """Mark this step's contact nodes (those of the contacts that do not sleep, from the
        step's start velocities ``state.sweep_buffers[0]``), set the metric and gather the
        colour-ordered off-diagonal blocks (once a step, after detection and ``A``)."""
        self.contact_node.zero_()
        for replay in self._prepare:
            replay()

    def set_contact_nodes(self, nodes: np.ndarray) -> None:
        """Mark exactly ``nodes`` [n] bool as the contact nodes, in place of :meth:`prepare`'s
        marking from the contacts (after it: a sweep with chosen contact nodes)."""
        nodes = np.asarray(nodes)
        if nodes.shape != (self._model.node_count,):
            raise ValueError(f"set_contact_nodes: expected a bool array of shape ({self._model.node_count},), found "
                             f"shape {nodes.shape}")
        upload(self.contact_node, nodes.astype(np.int32))
        self._list()

    def wake(self) -> bool:
        """Whether a sleeping contact has taken an impulse since :meth:`prepare`; if so, every
        contact's nodes are marked from now on (the sweep's iteration changes: the caller
        restarts its Chebyshev weights). Until then the impulse did not act (the Gauss-Seidel
        update of its nodes overwrote the push), and it stays in the contact's impulse, which
        every later sweep applies in full."""
        self.woken_launches()
        flag = self._flag_view if self._flag_view is not None else self.flag.numpy()
        if flag[0] == 0:
            return False
        self.wake_launches()
        if self.coarse is not None:  # its aggregates hold the newly marked contact nodes
            self.coarse.prepare()
        return True

    def island_contact(self, w: wp.array, parallel: bool) -> list[Callable[[], None]]:
        """Replays of the islands' step 2 in a sweep from its work velocities ``w`` [n] [m/s]
        (:func:`softvr.contact._node_gs_kernels.island_contact`; the sweep has islands): one
        thread over the islands and contacts, or (``parallel``) a thread per island node,
        contact and island: the forces zeroed, the contacts' impulses added (atomic), each island
        in contact solved."""
        m, st, d = self._model, self._state, self._model.device
        c = st.contacts
        if self._islands is None:
            raise ValueError("GaussSeidelSweep.island_contact: expected a sweep with rigid islands, found none")
        islands = self._islands
        start, nodes, local = islands
        if not parallel:
            return [replayer(wp.launch(_k.island_contact, dim=1, device=d, record_cmd=True,
                                       inputs=[*islands, m.row_start, m.block_col, st.blocks, st.b, self.metric,
                                               m.couplings.partner, self.cross_metric, self.contact_node,
                                               self._island_inverse, self._island_rhs, c.count, c.stencil_count,
                                               c.stencil_nodes, c.stencil_weights, c.frame, c.rigid_node,
                                               c.rigid_lever, c.impulse, self._island_force, w, st.v_hat]))]
        threads = stride_threads(d, min(c.capacity, CONTACT_THREADS))
        return [replayer(wp.launch(_k.island_force_clear, dim=nodes.shape[0], device=d, record_cmd=True,
                                   inputs=[nodes, self._island_force])),
                replayer(wp.launch(_k.island_force_add, dim=threads, device=d, record_cmd=True,
                                   inputs=[local, c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights,
                                           c.frame, c.rigid_node, c.rigid_lever, c.impulse, self._island_force,
                                           threads])),
                replayer(wp.launch(_k.island_respond, dim=start.shape[0] - 1, device=d, record_cmd=True,
                                   inputs=[*islands, m.row_start, m.block_col, st.blocks, st.b, self.metric,
                                           m.couplings.partner, self.cross_metric, self.contact_node,
                                           self._island_inverse, self._island_rhs, self._island_force, w,
                                           st.v_hat]))]

    def mark_tools(self, live: wp.array, threads: int) -> Callable[[], None]:
        """A replay setting :attr:`tool_live` from the sweep's ``live`` contacts [c]."""
        c, d = self._state.contacts, self._model.device
        return replayer(wp.launch(_k.tool_contacts, dim=threads, device=d, record_cmd=True,
                                  inputs=[c.count, c.rigid_node, self.tool_node, live, self.tool_live, threads]))

    def record(self, v: wp.array, contacts: Callable[[], None]) -> Callable[[], None]:
        """The node update of a sweep from ``v`` [n] [m/s], ``contacts`` in its middle."""
        m, st, d = self._model, self._state, self._model.device
        start, count = self._colouring.start, self._colouring.count
        n, w = m.node_count, self._work
        rows = [m.row_start, m.block_col, st.blocks, st.d_inv, m.couplings.partner, m.couplings.cross, st.b, m.fixed,
                st.fixed_velocity, self.contact_node]

        off = [self._order, self._off_start, self._off_col, self._off_blocks]
        # The C++ of _node_gs_kernels (_off_row, _plain_node, _copy) and of the coarse correction
        # (_node_gs_coarse_kernels.aggregate_velocity) reads these as plain contiguous memory.
        for name, array in (("b", st.b), ("v", v), ("work", w), ("v_hat", st.v_hat), ("d_inv", st.d_inv),
                            ("fixed_velocity", st.fixed_velocity), ("fixed", m.fixed),
                            ("off_blocks", self._off_blocks), ("blocks", st.blocks), ("q", st.q),
                            ("row_start", m.row_start), ("block_col", m.block_col)):
            if not array.is_contiguous:
                raise ValueError(f"GaussSeidelSweep.record: expected a contiguous array for {name}, found strides "
                                 f"{array.strides}")

        def colour(c: int, last: int) -> Callable[[], None]:
            return chunked_replayer(_k.gauss_seidel, int(start[c + 1] - start[c]),
                                    [*rows, *off, int(start[c]), last, w, st.v_hat], d, min_chunk=COLOUR_CHUNK)

        walk, listed = self._walk, [self._listed, self._listed_count]

        def colours(last: int) -> list:
            """The colours' updates of the sweep's first (``last`` 0, colours ascending, from
            ``w = v``) or second half (descending)."""
            if walk:
                return [replayer(wp.launch(_k.gauss_seidel_walk, dim=1, device=d, record_cmd=True,
                                           inputs=[*rows, *off, self._colour_start, self._free_end, *listed, last,
                                                   last, v, w, st.v_hat]))]
            return [colour(c, last) for c in (range(count) if last == 0 else range(count - 1, -1, -1))
                    if start[c + 1] > start[c]]

        def islands(last: int) -> list:
            if self._islands is None:
                return []
            return [replayer(wp.launch(_k.island_solve, dim=self._island_rhs.shape[0], device=d, record_cmd=True,
                                       inputs=[*self._islands, m.row_start, m.block_col, st.blocks, st.b,
                                               self.contact_node, self._island_inverse, self._island_rhs, last, w,
                                               st.v_hat]))]

        def touched() -> list:
            return [] if self._islands is None else self.island_contact(w, self.parallel)

        if self.parallel and n <= BLOCK_NODES_PER_LANE * CONTACT_BLOCK_THREADS:
            return self._record_block(v, contacts)
        replays = [] if walk else [chunked_replayer(_k.start, n, [v, w], d)]  # (the walk starts w itself)
        replays += colours(0) + islands(0)
        if walk:  # the backward walk sets w = v^ at the contact nodes itself
            replays += [replayer(wp.launch(_k.listed_contact_nodes, dim=1, device=d, record_cmd=True,
                                           inputs=[*rows, *off, self.node_omega, v, w, st.v_hat, *listed])),
                        *touched(), contacts]
        else:
            replays += [chunked_replayer(_k.contact_nodes, n, [*rows, *off, self.node_omega, v, w, st.v_hat], d),
                        *touched(), contacts, chunked_replayer(_k.projected, n, [self.contact_node, st.v_hat, w], d)]
        replays += colours(1) + islands(1)
        if self.coarse is not None:
            replays.append(self.coarse.correct)
        return in_order(*replays)

    def _record_block(self, v: wp.array, contacts: Callable[[], None]) -> Callable[[], None]:
        """:meth:`record` in one block before and one after ``contacts``
        (:func:`softvr.contact._node_block_kernels.gauss_seidel_before_contacts` and
        ``gauss_seidel_after_contacts``): the same updates in the same order, a barrier where a
        launch ended (each colour, the islands, the contact nodes, the coarse velocities)."""
        m, st, d = self._model, self._state, self._model.device
        c, w = st.contacts, self._work
        rows = [m.row_start, m.block_col, st.blocks, st.d_inv, m.couplings.partner, m.couplings.cross, st.b, m.fixed,
                st.fixed_velocity, self.contact_node, self._order, self._off_start, self._off_col, self._off_blocks,
                self._colour_start]
        if self._islands is None:
            none = wp.zeros(1, dtype=wp.int32, device=d)
            islands = [none, none, none, wp.zeros((1, 1, 1), dtype=wp.float64, device=d),
                       wp.zeros((1, 1), dtype=wp.float64, device=d), 0]
        else:
            islands = [*self._islands, self._island_inverse, self._island_rhs, self._islands[0].shape[0] - 1]
        force = self._island_force if self._islands is not None else wp.zeros(1, dtype=wp.vec3d, device=d)
        before = _block_launch(_bk.gauss_seidel_before_contacts, d,
                               [*rows, self.node_omega, v, w, st.v_hat, *islands, self.metric, self.cross_metric,
                                c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights, c.frame, c.rigid_node,
                                c.rigid_lever, c.impulse, force])
        if self.coarse is None:
            one, vec, mat = (wp.zeros(1, dtype=t, device=d) for t in (wp.int32, wp.vec3d, wp.mat33d))
            coarse = [one, one, st.q, vec, mat, mat, mat, one, vec, vec, 0]
        else:
            start, nodes, *rest = self.coarse.block_arrays
            coarse = [start, nodes, st.q, *rest, start.shape[0] - 1]
        after = _block_launch(_bk.gauss_seidel_after_contacts, d, [*rows, w, st.v_hat, *islands, *coarse])
        return in_order(before, contacts, after)


def _block_launch(kernel, device: str, inputs: list) -> Callable[[], None]:
    """A replay of ``kernel`` as one block of :data:`CONTACT_BLOCK_THREADS` lanes."""
    return replayer(wp.launch_tiled(kernel, dim=[1], block_dim=CONTACT_BLOCK_THREADS, device=device,
                                    record_cmd=True, inputs=inputs))


def free_first(colouring: NodeColouring, fixed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(order, free_end)``: ``colouring.order`` [n] with each colour's free nodes first (in
    their order) and its ``fixed`` [n] bool nodes after them, and where each colour's free
    nodes end [C] (colour ``c``'s free nodes are ``order[colouring.start[c] : free_end[c]]``).
    Within a colour no node reads another's update but a fixed node's (the pattern of ``A``
    has no row for one, so the colouring puts it in colour 0 whatever its columns), which is
    its fixed velocity before its update as after it (the sweeps' velocities hold it at fixed
    nodes), so any order within a colour gives the same bits; with the fixed nodes last, the
    forward walk (:func:`softvr.contact._node_gs_kernels.gauss_seidel_walk`) stops before them
    (the shoulder: 481 of its 1 247 nodes)."""
    order = colouring.order.copy()
    free_end = np.empty(colouring.count, np.int32)
    for c in range(colouring.count):
        s, e = colouring.start[c], colouring.start[c + 1]
        seg = order[s:e]
        order[s:e] = seg[np.argsort(fixed[seg], kind="stable")]
        free_end[c] = s + int((~fixed[seg]).sum())
    return order, free_end


def off_diagonal_rows(row_start: np.ndarray, block_col: np.ndarray, partner: np.ndarray,
                      order: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The block-CSR pattern of ``A``'s off-diagonal blocks with the rows in colour order:
    ``(start, col, source)``, row ``t`` (node ``order[t]``, [n]) holding the blocks
    ``source[start[t] : start[t + 1]]`` of ``A``'s ``blocks`` with columns ``col`` (each row's
    blocks in their order in ``A``, its diagonal block left out). A node with a pair partner
    (a spring-held rigid body's, whose ``D_A`` block is 6x6) gets an empty row: the sweep
    takes its update from ``A``'s own rows. ``row_start`` [n + 1], ``block_col`` [nb],
    ``partner`` [n] (-1: none) as in :class:`softvr.sim.NodeModel`."""
    row_start = np.asarray(row_start, np.int64)
    order = np.asarray(order, np.int64)
    node = np.repeat(np.arange(len(row_start) - 1), np.diff(row_start))
    keep = (np.asarray(block_col) != node) & (np.asarray(partner)[node] < 0)
    position = np.empty(len(order), np.int64)
    position[order] = np.arange(len(order))
    # A stable sort by the row's colour position keeps each row's blocks in A's order.
    source = np.flatnonzero(keep)
    source = source[np.argsort(position[node[source]], kind="stable")]
    start = np.concatenate([[0], np.cumsum(np.bincount(position[node[source]], minlength=len(order)))])
    return start.astype(np.int32), np.asarray(block_col)[source].astype(np.int32), source.astype(np.int32)


def gauss_seidel_spectrum(a: sp.spmatrix, order: np.ndarray) -> tuple[float, float]:
    """(lo, hi): the smallest and the largest eigenvalue of ``M^-1 A`` for the symmetric block
    Gauss-Seidel iteration over the nodes in ``order`` (``M = (D + L) D^-1 (D + U)``, D the
    3x3 node blocks, L and U the strict block triangles in that order), ``a`` [3 k, 3 k] the
    symmetric positive definite ``A`` of the ``k`` nodes solved for, ``order`` [k] a
    permutation of them. ``hi`` is 1 (M - A = L D^-1 U is positive semidefinite, and
    ``1 - lo`` is the largest eigenvalue of the similar ``R^T (D + L)^-1 L D^-1 U (D + U)^-1 R``
    (D = R R^T), found by Lanczos."""
    k = len(order)
    dofs = (3 * np.asarray(order)[:, None] + np.arange(3)).ravel()
    a = sp.csr_matrix(a)[dofs][:, dofs].tocoo()
    node_r, node_c = a.row // 3, a.col // 3
    diag = node_r == node_c
    blocks = np.zeros((k, 3, 3))
    blocks[node_r[diag], a.row[diag] % 3, a.col[diag] % 3] = a.data[diag]
    d = sp.block_diag(list(blocks), format="csr")
    lower_off = sp.csr_matrix((a.data[node_r > node_c], (a.row[node_r > node_c], a.col[node_r > node_c])),
                              shape=a.shape)
    upper_off = lower_off.T.tocsr()
    lu = spla.splu((d + lower_off).tocsc(), permc_spec="NATURAL")
    r_blocks = np.linalg.cholesky(blocks)
    r = sp.block_diag(list(r_blocks), format="csr")
    d_lu = spla.splu(d.tocsc())

    def apply(x):
        y = lu.solve(r @ x, trans="T")  # (D + U)^-1 R x
        y = lower_off @ d_lu.solve(upper_off @ y)
        return r.T @ lu.solve(y)

    op = spla.LinearOperator(a.shape, matvec=apply, dtype=float)
    # A fixed start vector: the bounds set the Chebyshev weights, so every run must get the same.
    start = np.random.default_rng(0).standard_normal(a.shape[0])
    top = float(spla.eigsh(op, k=1, which="LA", return_eigenvectors=False, tol=1e-8, v0=start)[0])
    return max(1.0 - top, 1e-9), 1.0
