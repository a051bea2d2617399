"""What a player shows, as plain data (:class:`Drawable`), and the one way it is put into and
kept up to date in a :class:`~softvr.render.SurfaceRenderer` (:class:`SurfaceDrawing`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DRAWABLE_KINDS", "DRAWABLE_LAYERS", "PLANE_COLOR", "PLANE_TILES", "SPHERE_COLOR", "Drawable",
           "SurfaceDrawing", "plane_drawable", "pose_matrix", "sphere_drawable"]

#: ``mesh``: a surface that moves or deforms (its vertices change); ``plane``: a static square of
#: side ``size`` (drawn as a checkerboard of :data:`PLANE_TILES` tiles); ``sphere``: a static sphere
#: of radius ``size``.
DRAWABLE_KINDS = ("mesh", "plane", "sphere")

#: ``render``: a body's render surface (the window's ``r`` key shows and hides it); ``scenery``:
#: planes and static spheres, always shown; ``hidden``: built (a body's skin, for contacts and
#: start checks) but drawn by something else (its volume), so never drawn as a surface.
DRAWABLE_LAYERS = ("render", "scenery", "hidden")

#: Colours of a plane and a sphere drawn without one of their own: SurfaceRenderer's defaults
#: (tests/cave/test_command.py holds them equal), so that every view of a scene agrees.
PLANE_COLOR = (0.55, 0.57, 0.6)
SPHERE_COLOR = (0.75, 0.75, 0.78)

#: Tiles per side of a drawn plane's checkerboard (motion over it shows).
PLANE_TILES = 12


@dataclass(frozen=True, eq=False)
class Drawable:
    """One thing a player shows, now: plain arrays, no renderer object.

    Attributes
    ----------
    name : str
        The body (or plane / sphere) it draws.
    kind : str
        One of :data:`DRAWABLE_KINDS`.
    vertices : ndarray, shape [n, 3] [m]
        World positions now (a plane: its square's 4 corners; a sphere: none, shape [0, 3]).
    triangles : ndarray of int32, shape [t, 3]
        Vertex indices, counter-clockwise seen from outside (a plane: its 2; a sphere: none).
    color : tuple of 3 float
        RGB in [0, 1].
    opacity : float
        In (0, 1].
    pose : ndarray, shape [4, 4], or None
        World <- frame of what carries it rigidly (a rigid, fixed or kinematic body: its
        position and rotation; a plane: its centre, z along its normal; a sphere: its centre);
        None for a deforming surface (FEM, cloth).
    layer : str
        One of :data:`DRAWABLE_LAYERS`.
    size : float [m]
        A plane's side or a sphere's radius (0 for a mesh).
    """

    name: str
    kind: str
    vertices: np.ndarray
    triangles: np.ndarray
    color: tuple
    opacity: float = 1.0
    pose: np.ndarray | None = None
    layer: str = "render"
    size: float = 0.0

    @property
    def point(self) -> np.ndarray:
        """A plane's centre or a sphere's centre [3] [m] (the pose's translation)."""
        assert self.pose is not None, f"{self.kind} {self.name!r} has no pose"
        return self.pose[:3, 3]

    @property
    def normal(self) -> np.ndarray:
        """A plane's unit normal [3] (the pose's z axis)."""
        assert self.pose is not None, f"{self.kind} {self.name!r} has no pose"
        return self.pose[:3, 2]


def pose_matrix(rotation, position) -> np.ndarray:
    """World <- frame [4, 4] of ``rotation`` [3, 3] and ``position`` [3] [m]."""
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, position
    return pose


def plane_drawable(name: str, point, normal, size: float, color=PLANE_COLOR) -> Drawable:
    """A plane through ``point`` [3] [m] facing ``normal`` [3], drawn as a square of side ``size``
    [m]: its pose has z along the unit normal (x, y any orthonormal pair in the plane)."""
    z = np.asarray(normal, float) / np.linalg.norm(normal)
    # The world axis least along the normal spans the plane with it without a near-zero cross product.
    x = np.cross(z, np.eye(3)[np.argmin(np.abs(z))])
    x /= np.linalg.norm(x)
    pose = pose_matrix(np.c_[x, np.cross(z, x), z], point)
    h = float(size) / 2
    corners = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    vertices = corners @ pose[:3, :3].T + pose[:3, 3]
    return Drawable(name, "plane", vertices, np.array([[0, 1, 2], [0, 2, 3]], np.int32), tuple(color), 1.0, pose,
                    "scenery", float(size))


def sphere_drawable(name: str, center, radius: float, color=SPHERE_COLOR) -> Drawable:
    """A static sphere of ``radius`` [m] at ``center`` [3] [m]."""
    return Drawable(name, "sphere", np.zeros((0, 3)), np.zeros((0, 3), np.int32), tuple(color), 1.0,
                    pose_matrix(np.eye(3), center), "scenery", float(radius))


class SurfaceDrawing:
    """A player's drawables in a :class:`~softvr.render.SurfaceRenderer`: added once
    (:meth:`__init__`), their vertices updated each frame (:meth:`update`); ``handles`` maps
    each drawable's index to its renderer handle (hidden ones have none)."""

    def __init__(self, renderer, drawables: list[Drawable]):
        self.renderer = renderer
        self.handles: dict[int, int] = {}
        for k, d in enumerate(drawables):
            if d.layer == "hidden":
                continue
            if d.kind == "plane":
                self.handles[k] = renderer.add_plane(point=d.point, normal=d.normal, size=d.size, color=d.color,
                                                     tiles=PLANE_TILES)
            elif d.kind == "sphere":
                self.handles[k] = renderer.add_sphere(d.point, d.size, color=d.color, opacity=d.opacity)
            else:
                self.handles[k] = renderer.add_mesh(d.vertices, d.triangles, color=d.color, opacity=d.opacity)

    def update(self, drawables: list[Drawable]) -> None:
        """Move the meshes to ``drawables``' vertices now (planes and spheres are static)."""
        for k, handle in self.handles.items():
            if drawables[k].kind == "mesh":
                self.renderer.update(handle, drawables[k].vertices)

    def layer_handles(self, drawables: list[Drawable], layer: str) -> list[int]:
        """The renderer handles of the drawables on ``layer``."""
        return [h for k, h in self.handles.items() if drawables[k].layer == layer]
