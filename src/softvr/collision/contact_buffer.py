"""A fixed-capacity set of contacts as flat arrays, filled by the collision kernels and solved
in place by the contact kernels (after NVIDIA Newton's ``Contacts``).

Detection kernels append with an atomic counter (``count[0]``); every contact carries a key
unique in the scene (:func:`~softvr.collision.contacts.contact_keys`, stored as its uint64
bits) by which the next step finds it again: the ``carried_*`` arrays hold the previous step's
contacts sorted by key, with what each carries over (warm-start impulse, adhesion intensity,
tangential slip), and the solve kernel matches this step's contacts against them.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import warp as wp

__all__ = ["ContactBuffer"]


@dataclass
class ContactBuffer:
    """Contacts of one step, capacity ``c`` (every array but ``count`` and ``carried_count`` [c]).

    Attributes
    ----------
    count : wp.array(int32) [1]
        Contacts written this step (the rest of each array is stale).
    key : wp.array(uint64)
        Scene-unique key (bits of :func:`~softvr.collision.contacts.contact_keys`).
    body_a, body_b : wp.array(int32)
        Bodies of the two sides; ``body_b`` = -1 for static geometry.
    offset_a, offset_b : wp.array(vec3d) [m]
        Where each side's impulse acts, from its body's centre (world frame).
    point_a, point_b : wp.array(vec3d) [m]
        Contact points P on a and P' on b.
    normal : wp.array(vec3d)
        Unit normal from b towards a.
    gap : wp.array(float64) [m]
        Signed distance along the normal (negative: penetration).
    area : wp.array(float64) [m^2]
        Local area the contact stands for (thesis 4.3.1, projected on the contact plane).
    friction : wp.array(float64)
        Coulomb coefficient.
    material_a, material_b : wp.array(int32)
        Adhesion material rows of the two sides (-1: not adhesive).
    impulse : wp.array(vec3d) [N s]
        Solution: (normal, tangent 1, tangent 2) impulse in ``frame``.
    frame : wp.array(mat33d)
        Rows n, t1 (along the unconstrained tangential velocity), t2 = n x t1.
    gap_after : wp.array(float64) [m]
        Linearized gap at the end of the step.
    intensity : wp.array(float64)
        Adhesion intensity beta after the step; -1 where the contact is not tracked.
    slip : wp.array(vec3d) [m]
        Tangential slip of a bonded contact since bonding, after the step (0: none).
    carried_count : wp.array(int32) [1]
    carried_key : wp.array(uint64)
        The previous step's keys, ascending.
    carried_impulse : wp.array(vec3d) [N s]
        Their world impulses (warm starts).
    carried_intensity : wp.array(float64)
        Their adhesion intensities (-1: not tracked).
    carried_slip : wp.array(vec3d) [m]
    """

    count: wp.array
    key: wp.array
    body_a: wp.array
    body_b: wp.array
    offset_a: wp.array
    offset_b: wp.array
    point_a: wp.array
    point_b: wp.array
    normal: wp.array
    gap: wp.array
    area: wp.array
    friction: wp.array
    material_a: wp.array
    material_b: wp.array
    impulse: wp.array
    frame: wp.array
    gap_after: wp.array
    intensity: wp.array
    slip: wp.array
    carried_count: wp.array
    carried_key: wp.array
    carried_impulse: wp.array
    carried_intensity: wp.array
    carried_slip: wp.array

    @classmethod
    def allocate(cls, capacity: int, device: str) -> ContactBuffer:
        """Zeroed arrays for ``capacity`` contacts on ``device``."""
        types = {"key": wp.uint64, "body_a": wp.int32, "body_b": wp.int32, "offset_a": wp.vec3d,
                 "offset_b": wp.vec3d, "point_a": wp.vec3d, "point_b": wp.vec3d, "normal": wp.vec3d,
                 "gap": wp.float64, "area": wp.float64, "friction": wp.float64, "material_a": wp.int32,
                 "material_b": wp.int32, "impulse": wp.vec3d, "frame": wp.mat33d, "gap_after": wp.float64,
                 "intensity": wp.float64, "slip": wp.vec3d, "carried_key": wp.uint64, "carried_impulse": wp.vec3d,
                 "carried_intensity": wp.float64, "carried_slip": wp.vec3d}
        arrays = {name: wp.zeros(capacity, dtype=dtype, device=device) for name, dtype in types.items()}
        return cls(count=wp.zeros(1, dtype=wp.int32, device=device),
                   carried_count=wp.zeros(1, dtype=wp.int32, device=device), **arrays)

    @property
    def capacity(self) -> int:
        return self.key.shape[0]

    def views(self) -> dict[str, np.ndarray]:
        """NumPy views of every per-contact array (CPU only: they share the memory), keys as
        int64 (:func:`~softvr.collision.contacts.unpack_keys` reads them)."""
        out = {f.name: getattr(self, f.name).numpy() for f in fields(self)
               if f.name not in ("count", "carried_count") and not f.name.startswith("carried_")}
        out["key"] = out["key"].view(np.int64)
        return out

    def numpy(self, views: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Copies of this step's contacts (the first ``count`` of each of :meth:`views`)."""
        count = min(int(self.count.numpy()[0]), self.capacity)
        return {name: view[:count].copy() for name, view in (views or self.views()).items()}
