"""Implicit adhesion (thesis ch. 4) on the whole-scene node arrays: the contacts' areas,
intensities and tangential slips, carried from step to step by contact key and handed to and
from the per-object path's :class:`~softvr.contact.AdhesionState` by key (kernels in
:mod:`softvr.contact._node_adhesion_kernels`; the bounds of eq. 4.16 act in the sweeps of
:class:`~softvr.contact.NodeSolve`). Works on :class:`softvr.sim.NodeModel` /
:class:`softvr.sim.NodeState` or any objects with those attributes.

A contact's area is its feature's surface projected on the contact plane, as on the
per-object path (docs/adhesion.md, "Contact areas"): a third of every incident triangle's for
a vertex, the smaller of the two sides' for two edges; a collision point that is no surface
vertex has none and does not adhere. Where two bodies meet face to face, with vertex-triangle
contacts both ways, only one way bonds (:func:`softvr.contact._node_adhesion_kernels.share_patches`),
so that the patch counts once. A rigid body's box or sphere primitive's contact
has the rigid path's area (a box corner its share of the face turned to the plane, a sphere
its cap within the margin), and every side its body's or plane's adhesion.
"""

from __future__ import annotations

from collections.abc import Callable

import weakref

import numpy as np
import warp as wp

from softvr.contact import _node_adhesion_kernels as _k
from softvr.contact.adhesion import AdhesionState
from softvr.device import chunked_replayer, cpu_workers, in_order, load_kernels, replayer, stride_threads, upload

__all__ = ["NodeAdhesion"]

#: Threads striding over a step's contacts in :func:`_node_adhesion_kernels.prepare` on CUDA
#: (on the CPU: one per core).
PREPARE_THREADS_CUDA = 4096


class _CarriedAdhesionState(AdhesionState):
    """An :class:`AdhesionState` read from the node arrays' carried table when first used (most
    steps nobody reads it: the table stays on the device and nothing is copied), or from the
    copy :meth:`detach` took before a later step wrote the table again."""

    def __init__(self, adhesion: NodeAdhesion):
        self._source: NodeAdhesion | None = adhesion
        self._rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._intensity: dict | None = None
        self._slip: dict = {}

    def detach(self) -> None:
        """Copy the table's rows out, unless they were read already."""
        if self._source is not None and self._intensity is None:
            self._rows = self._source.rows()
        self._source = None

    def _read(self) -> None:
        if self._intensity is None:
            rows = self._rows if self._source is None else self._source.rows()
            assert rows is not None  # detach copied them
            keys, beta, slip = rows
            self._source = self._rows = None
            keys = keys.view(np.int64).tolist()
            self._intensity = {k: float(b) for k, b in zip(keys, beta) if b >= 0}
            self._slip = {k: s.copy() for k, s, b in zip(keys, slip, beta) if b >= 0 and np.any(s != 0)}

    def __deepcopy__(self, memo) -> AdhesionState:
        # A saved scene state keeps the dictionaries, not the stepper the table belongs to.
        out = AdhesionState()
        out.intensity, out.slip = dict(self.intensity), {k: s.copy() for k, s in self.slip.items()}
        return out

    @property
    def intensity(self) -> dict:
        self._read()
        assert self._intensity is not None  # _read sets it
        return self._intensity

    @intensity.setter
    def intensity(self, value: dict) -> None:
        self._read()
        self._intensity = value

    @property
    def slip(self) -> dict:
        self._read()
        return self._slip

    @slip.setter
    def slip(self, value: dict) -> None:
        self._read()
        self._slip = value


class NodeAdhesion:
    """The adhesion of a scene on node arrays: per contact its key, materials, intensity, and a
    table of the last step's contacts by key (``c`` = the contacts' capacity).

    Parameters
    ----------
    model, state
        :class:`softvr.sim.NodeModel`, :class:`softvr.sim.NodeState`.
    materials : ndarray [m, 7]
        Adhesion parameters per material, columns :data:`softvr.sim.model.ADHESION_COLUMNS` (SI).
    body_material : ndarray of int [bodies]
        Row of each body's adhesion in ``materials`` (-1: none).
    plane_material, sphere_material, mesh_material : ndarray of int [planes], [spheres], [meshes]
        Row of each static plane's, sphere's and triangle mesh's adhesion (-1: none).
    parallel : bool, optional
        The evolve with a thread per contact (a GPU's form); None: on any device but the CPU.
    """

    def __init__(self, model, state, materials: np.ndarray, body_material, plane_material, sphere_material,
                 mesh_material, parallel: bool | None = None):
        d = model.device
        self.parallel = (not wp.get_device(d).is_cpu) if parallel is None else bool(parallel)
        cap = state.contacts.capacity
        p = model.point_count
        triangles = model.triangles.numpy()
        corners = triangles.ravel()
        order = np.argsort(corners, kind="stable")
        ad = _k.NodeAdhesionArrays()
        ad.key = wp.zeros(cap, dtype=wp.uint64, device=d)
        ad.material_a = wp.full(cap, -1, dtype=wp.int32, device=d)
        ad.material_b = wp.full(cap, -1, dtype=wp.int32, device=d)
        ad.intensity = wp.full(cap, -1.0, dtype=wp.float64, device=d)
        ad.carried_count = wp.zeros(1, dtype=wp.int32, device=d)
        ad.carried_key = wp.zeros(cap, dtype=wp.uint64, device=d)
        ad.carried_impulse = wp.zeros(cap, dtype=wp.vec3d, device=d)
        ad.carried_intensity = wp.full(cap, -1.0, dtype=wp.float64, device=d)
        ad.carried_slip = wp.zeros(cap, dtype=wp.vec3d, device=d)
        ad.materials = wp.array(np.asarray(materials, float).reshape(-1, 7), dtype=wp.float64, device=d)
        ad.body_material = wp.array(np.asarray(body_material, np.int32), dtype=wp.int32, device=d)
        ad.plane_material, ad.sphere_material, ad.mesh_material = (
            wp.array(np.asarray(m, np.int32).reshape(-1), dtype=wp.int32, device=d)
            for m in (plane_material, sphere_material, mesh_material))
        two_sided = [int(model.surfaces[b].two_sided) if b in model.surfaces else 0
                     for b in range(len(model.body_node_start) - 1)]
        ad.body_two_sided = wp.array(np.asarray(two_sided, np.int32), dtype=wp.int32, device=d)
        ad.vertex_start = wp.array(np.searchsorted(corners[order], np.arange(p + 1)).astype(np.int32),
                                   dtype=wp.int32, device=d)
        ad.vertex_triangles = wp.array((order // 3).astype(np.int32), dtype=wp.int32, device=d)
        bodies = len(model.body_node_start) - 1
        ad.pair_bonded = wp.zeros((bodies, bodies), dtype=wp.int32, device=d)
        ad.pair_bonded_area = wp.zeros((bodies, bodies), dtype=wp.float64, device=d)
        self.arrays = ad
        self._model, self._state = model, state
        self._issued: weakref.ref | None = None  # the last state handed out, while someone holds it

    def record(self, dt: float) -> tuple[Callable[[], None], list]:
        """Replays for a step of ``dt`` [s]: the one before the sweeps (after detection) and,
        per sweep buffer of ``state.sweep_buffers``, the one after them (after the residual
        has set ``gap_after``; :meth:`detach_issued` first)."""
        m, st = self._model, self._state
        c, d = st.contacts, m.device
        for kernel in (_k.prepare, _k.clear_bonded, _k.count_bonded, _k.share_patches, _k.evolve):
            load_kernels(kernel, d)
        if m.rigid is not None:
            rigid_key, rigid_area = m.rigid.state.contacts.key, m.rigid.state.contacts.area
        else:  # no primitive contacts to read
            rigid_key, rigid_area = wp.zeros(0, dtype=wp.uint64, device=d), wp.zeros(0, dtype=wp.float64, device=d)
        threads = cpu_workers() if wp.get_device(d).is_cpu else PREPARE_THREADS_CUDA
        prepare = chunked_replayer(_k.prepare, threads,
                                   [self.arrays, c.count, c.kind, c.column, c.point, c.other, c.face, c.frame,
                                    rigid_key, rigid_area, st.point_x, m.point_body, m.body_point_start_wp,
                                    m.triangles, m.edge_body, m.body_edge_start, m.edge_faces, c.area, c.stiffness,
                                    c.slip, c.impulse, threads], d, min_chunk=1)
        if m.meshes:  # vertex-triangle contacts: one way of a face-to-face patch's two adheres
            ad = self.arrays
            contacts = [c.count, c.kind, c.point, c.other, m.point_body]
            prepare = in_order(
                prepare,
                replayer(wp.launch(_k.clear_bonded, dim=ad.pair_bonded.shape, device=d, record_cmd=True,
                                   inputs=[ad])),
                replayer(wp.launch(_k.count_bonded, dim=threads, device=d, record_cmd=True,
                                   inputs=[ad, *contacts, c.area, c.stiffness, threads])),
                chunked_replayer(_k.share_patches, threads, [ad, *contacts, c.stiffness, threads], d, min_chunk=1))
        # The evolve kernel rewrites the carried table: a state handed out before and still
        # held must copy its rows out first (detach_issued, which the caller runs on the host
        # before these launches).
        evolve = [self._record_parallel_evolve(dt, buf) if self.parallel else
                  replayer(wp.launch(_k.evolve, dim=1, device=d, record_cmd=True,
                                     inputs=[self.arrays, c.count, c.frame, c.impulse, c.gap_after,
                                             c.stencil_count, c.stencil_nodes, c.stencil_weights,
                                             c.rigid_node, c.rigid_lever, m.fixed, buf, c.area, c.stiffness,
                                             c.slip, float(dt)]))
                  for buf in st.sweep_buffers]
        return prepare, evolve

    def _record_parallel_evolve(self, dt: float, v: wp.array) -> Callable[[], None]:
        """The evolve with a thread per contact (:attr:`parallel`; kernels ``evolve_parallel``,
        ``carry_parallel``): the bonds evolved and keyed, the whole buffer's keys radix-sorted
        with their rows (the count stays on the device), the carried table written in key order."""
        m, c, d = self._model, self._state.contacts, self._model.device
        for kernel in (_k.evolve_parallel, _k.carry_parallel):
            load_kernels(kernel, d)
        cap = c.capacity
        threads = stride_threads(d, PREPARE_THREADS_CUDA)
        sort_key, sort_row = wp.zeros(2 * cap, dtype=wp.uint64, device=d), wp.zeros(2 * cap, dtype=wp.int32, device=d)
        evolve = replayer(wp.launch(_k.evolve_parallel, dim=threads, device=d, record_cmd=True,
                                    inputs=[self.arrays, c.count, c.frame, c.impulse, c.gap_after, c.stencil_count,
                                            c.stencil_nodes, c.stencil_weights, c.rigid_node, c.rigid_lever, m.fixed,
                                            v, c.area, c.stiffness, c.slip, float(dt), sort_key, sort_row, threads]))
        carry = replayer(wp.launch(_k.carry_parallel, dim=threads, device=d, record_cmd=True,
                                   inputs=[self.arrays, c.count, c.frame, c.impulse, c.slip, sort_row, threads]))

        def run() -> None:
            evolve()
            wp.utils.radix_sort_pairs(sort_key, sort_row, cap)
            carry()

        return run

    def carry_in(self, adhesion: AdhesionState, warm: dict) -> None:
        """The per-object path's intensities and slips (and the warm starts of those contacts,
        which may pull), by key, as the carried table."""
        self.detach_issued()
        ad = self.arrays
        cap = ad.carried_key.shape[0]
        keys = np.array(sorted(adhesion.intensity), np.int64)
        bits = np.sort(keys.view(np.uint64))[:cap]  # the kernels compare keys as uint64
        keys = bits.view(np.int64).tolist()
        n = len(keys)
        intensity = np.full(cap, -1.0)
        intensity[:n] = [adhesion.intensity[k] for k in keys]
        slip, impulse = np.zeros((cap, 3)), np.zeros((cap, 3))
        slip[:n] = np.array([adhesion.slip.get(k, (0.0, 0.0, 0.0)) for k in keys], float).reshape(-1, 3)
        impulse[:n] = np.array([warm.get(k, (0.0, 0.0, 0.0)) for k in keys], float).reshape(-1, 3)
        padded = np.zeros(cap, np.uint64)
        padded[:n] = bits
        for dst, src in ((ad.carried_count, [n]), (ad.carried_key, padded), (ad.carried_intensity, intensity),
                         (ad.carried_slip, slip), (ad.carried_impulse, impulse)):
            upload(dst, src)

    def rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Host copies of the carried table's rows: keys (uint64) [k], intensities [k], slips
        [k, 3] [m]."""
        ad = self.arrays
        n = int(ad.carried_count.numpy()[0])
        return (ad.carried_key.numpy()[:n].copy(), ad.carried_intensity.numpy()[:n].copy(),
                ad.carried_slip.numpy()[:n].copy())

    def state(self) -> AdhesionState:
        """The intensities and slips of the last step's contacts, by key, read from the arrays
        when first used (copied out first if a later step is about to write them)."""
        self.detach_issued()
        view = _CarriedAdhesionState(self)
        self._issued = weakref.ref(view)
        return view

    def detach_issued(self) -> None:
        """Let the state handed out last, if still held, copy the table before it changes."""
        held = self._issued() if self._issued is not None else None
        if held is not None:
            held.detach()
        self._issued = None

    def carried_out(self) -> AdhesionState:
        """:meth:`state` as a plain :class:`AdhesionState` for the per-object path."""
        view = _CarriedAdhesionState(self)  # read at once: no need to track it
        out = AdhesionState()
        out.intensity, out.slip = view.intensity, view.slip
        return out
