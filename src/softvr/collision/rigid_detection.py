"""Contact generation of a whole rigid scene, one compiled launch per pair kind, into a
:class:`~softvr.collision.contact_buffer.ContactBuffer` (whole-scene arrays:
:class:`softvr.sim.RigidModel` / :class:`softvr.sim.RigidState`, or any objects with those
attributes). The kernels are the array form of :func:`points_vs_plane` (with
:meth:`CollisionSurface.facing_vertex_area`), :func:`box_vs_plane`, :func:`sphere_vs_plane`,
:func:`sphere_vs_sphere` and :func:`box_vs_box`; the launches are recorded once and replayed every step.
"""

from __future__ import annotations

import warp as wp

from softvr.collision import _primitive_kernels as _k
from softvr.device import load_kernels, replayer

__all__ = ["Detection", "record_detection"]


class Detection:
    """The recorded detection launches of a scene, in order, and the scratch arrays they use."""

    def __init__(self, launches: list, scratch: list):
        self.launches, self._scratch = launches, scratch
        self._replays = [replayer(launch) for launch in launches]

    def launch(self) -> None:
        for replay in self._replays:
            replay()


def _outputs(buffer) -> list:
    c = _k.ContactOut()
    for name in ("count", "key", "body_a", "body_b", "offset_a", "offset_b", "point_a", "point_b", "normal", "gap",
                 "area", "friction", "material_a", "material_b"):
        setattr(c, name, getattr(buffer, name))
    return [c]


def record_detection(model, state, dt: float) -> Detection:
    """The launches that fill ``state.contacts`` from the poses and
    the unconstrained velocities (``state.free_velocity``: speculative contacts over ``dt``
    [s]); one per pair kind the scene has."""
    out = _outputs(state.contacts)
    planes = model.plane_normal.shape[0]
    pose = [state.body_position, state.body_orientation, state.free_velocity]
    plane = [model.plane_point, model.plane_normal, model.plane_friction, model.plane_material]
    launches = []

    def record(kernel, dim, inputs):
        load_kernels(kernel, model.device)
        launches.append(wp.launch(kernel, dim=dim, inputs=inputs + out, device=model.device, record_cmd=True))

    points = model.point_body.shape[0]
    if points and planes:
        record(_k.points_plane, (points, planes),
               pose + [model.point_body, model.point_feature, model.point_local, model.point_margin,
                       model.point_material, model.point_two_sided, model.point_triangles, model.triangle_normal,
                       model.triangle_area] + plane + [float(dt)])
    boxes = model.box_body.shape[0]
    if boxes and planes:
        record(_k.boxes_plane, (boxes, planes),
               pose + [model.box_body, model.box_half, model.box_material, model.box_plane_margin] + plane
               + [float(dt)])
    spheres = model.sphere_body.shape[0]
    if spheres and planes:
        record(_k.spheres_plane, (spheres, planes),
               [state.body_position, state.free_velocity, model.sphere_body, model.sphere_radius,
                model.sphere_material, model.sphere_plane_margin] + plane + [float(dt)])
    if model.sphere_pairs.shape[0]:
        record(_k.sphere_pairs, model.sphere_pairs.shape[0],
               [state.body_position, state.free_velocity, model.sphere_body, model.sphere_radius,
                model.sphere_material, model.sphere_pairs, model.sphere_pair_margin, float(model.friction), float(dt)])
    pairs = model.box_pairs.shape[0]
    scratch = []
    if pairs:
        scratch = [wp.zeros((pairs, 16), dtype=dtype, device=model.device)
                   for dtype in (wp.vec3d, wp.float64, wp.int32, wp.int32)]
        record(_k.box_pairs, pairs, pose + [model.box_body, model.box_half, model.box_material, model.box_pairs,
                                            model.box_pair_margin, float(model.friction), float(dt)] + scratch)
    return Detection(launches, scratch)
