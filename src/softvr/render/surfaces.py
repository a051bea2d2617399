"""Off-screen rendering of moving triangle surfaces (soft bodies, cloth, rigid boxes) with VTK.

:class:`SurfaceRenderer` keeps one VTK pipeline per surface: the vertex positions live in a
numpy array that VTK reads in place, so :meth:`SurfaceRenderer.update` costs a copy of the
new positions and a normal recomputation (``vtkPolyDataNormals``), not a rebuilt pipeline.
Static scenery is a ground quad (:meth:`~SurfaceRenderer.add_plane`, checkered so sliding
and rolling are visible) and spheres (:meth:`~SurfaceRenderer.add_sphere`). A light kit
(key, fill, back and head lights) and Phong shading make the shapes read as solids.

A :class:`~softvr.volume.Volume` (a CT, deformed or not) can be drawn in the same image
(:meth:`~SurfaceRenderer.add_volume`, :meth:`~SurfaceRenderer.update_volume`): it is ray
cast in software and composited by depth with the surfaces, so a probe in front of the
volume hides it and one inside or behind it is hidden by what lies in front.

:func:`softvr.volume.boundary_faces` gives the outward-oriented surface of a tetrahedral
mesh, the triangles a FEM body is drawn with.

Like :class:`~softvr.render.VolumeRenderer`, it renders without a display (EGL, else
OSMesa; see :func:`~softvr.render.offscreen_backend`).
"""

from __future__ import annotations

import numpy as np

from softvr.render._offscreen import OffscreenView
from softvr.render._scene import VolumeScene, check_volume
from softvr.errors import InputError
from softvr.render._backend import new_offscreen_window, new_onscreen_window, offscreen_backend, require_display
from softvr.render.camera import Camera
from softvr.render.presets import resolve_preset
from softvr.render.raycast import RayCaster, volume_bounds

__all__ = ["PLANE_DEPTH_OFFSET", "SurfaceRenderer", "merge_changed"]

#: (factor, units) of the polygon offset a plane is drawn with (``glPolygonOffset``): its depths
#: pushed back by ``factor`` times its depth slope plus ``units`` steps of the depth buffer, so
#: that a body resting on it (a box's face on the ground, a cloth on a wall: the same depth up to
#: the contact's few tenths of a millimetre) is drawn over it instead of flickering with it. 1000
#: steps of a 24-bit buffer are ~0.1 mm at 1 m behind a fitted camera, ~5 mm at 2 m in a CAVE
#: screen's frustum (near 0.05 m, far 100 m): deeper than any contact's overlap, shallower than
#: what a viewer sees as a gap.
PLANE_DEPTH_OFFSET = (2.0, 1000.0)

def _rgb(color, what: str) -> tuple[float, float, float]:
    c = np.asarray(color, float).reshape(-1)
    if c.shape != (3,) or not np.isfinite(c).all() or (c < 0).any() or (c > 1).any():
        raise InputError(what, "an RGB triple in [0, 1]", repr(color))
    return float(c[0]), float(c[1]), float(c[2])


def _vec3(value, what: str, unit: str) -> np.ndarray:
    v = np.asarray(value, float).reshape(-1)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise InputError(what, f"3 finite numbers [{unit}]", repr(value))
    return v


def _positive(value, what: str, unit: str) -> float:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and np.isfinite(value) and value > 0
    if not ok:
        raise InputError(what, f"a finite number > 0 [{unit}]", repr(value))
    return float(value)


class _Item:
    """One surface or volume: its kind, actor (a ``vtkVolume`` for a volume) and (for meshes)
    the vertex array VTK reads from and the indices of the vertices that triangles use (None:
    all); ``scene`` is a volume's :class:`~softvr.render._scene.VolumeScene`."""

    def __init__(self, kind: str, actor, points=None, polydata=None, array=None, used=None, scene=None):
        self.kind, self.actor, self.points, self.polydata, self.array = kind, actor, points, polydata, array
        self.used, self.scene = used, scene

    def bounds(self) -> np.ndarray:
        """(xmin, xmax, ymin, ymax, zmin, zmax) [m]."""
        if self.scene is not None:
            return np.asarray(self.scene.bounds(), float)
        if self.array is not None:
            x = self.array if self.used is None else self.array[self.used]
            return np.stack([x.min(axis=0), x.max(axis=0)], axis=1).ravel()
        return np.asarray(self.actor.GetBounds(), float)


def merge_changed(first, second):
    """What changed in a volume's voxels over two updates, as :meth:`RayCaster.cast
    <softvr.render.RayCaster.cast>` takes it: True (everything), False or None (nothing) or an
    inclusive index box ``(lo [3], hi [3])``; two boxes give the box around both."""
    if first is True or second is True:
        return True
    if first is None or first is False:
        return second if second is not None else False
    if second is None or second is False:
        return first
    return np.minimum(first[0], second[0]), np.maximum(first[1], second[1])


class _CastVolume:
    """A volume drawn by the Warp ray caster over the surfaces (:meth:`SurfaceRenderer.add_volume`):
    its :class:`~softvr.render.RayCaster` and current volume; ``prop`` is a ``vtkVolume`` without a
    mapper, never drawn, that carries the item's visibility."""

    def __init__(self, preset, sample_distance: float):
        from vtkmodules.vtkRenderingCore import vtkVolume  # noqa: PLC0415

        resolve_preset(preset)  # reject unknown names now, not at the first render
        self._preset_arg = preset
        self.caster: RayCaster | None = None
        self.sample_distance = sample_distance
        self.prop = vtkVolume()
        self.volume = None
        #: What changed in the voxels since the last cast (:func:`merge_changed`).
        self.changed: bool | tuple = True

    def update(self, volume, changed=True) -> None:
        """Show ``volume`` from the next render on (its transfer function resolved for it);
        ``changed``: its voxels that differ from the last update's (:func:`merge_changed`)."""
        check_volume(volume)
        preset = resolve_preset(self._preset_arg, volume)
        if self.caster is None:
            self.caster = RayCaster(preset, self.sample_distance)
        self.caster.preset = preset
        self.volume = volume
        self.changed = merge_changed(self.changed, changed)

    def bounds(self) -> tuple[float, ...]:
        return volume_bounds(self.volume)


class SurfaceRenderer(OffscreenView):
    """Render triangle surfaces that move every frame to RGB images, off-screen.

    Parameters
    ----------
    width, height : int [pixels]
        Image size.
    camera : Camera or str, optional
        A :class:`~softvr.render.Camera` or a view name; default ``Camera("iso")``. Views are
        on the world axes with z up (``"front"`` looks from +y), which suits z-up physics scenes.
    bounds : array_like of 6 float, optional [m]
        World box (xmin, xmax, ymin, ymax, zmin, zmax) the camera is fitted to. Default: the
        meshes, spheres and volumes at the first :meth:`render` (planes only when there is
        nothing else). The camera then stays fixed until :meth:`set_camera` or :meth:`reset_camera`.
    background, background_top : tuple of 3 float
        Background RGB in [0, 1] at the bottom and top of the image (a vertical gradient;
        equal colours give a flat background).
    antialias : bool
        FXAA edge smoothing (a post-process, so edge pixels blend with the background);
        off-screen only.
    backend : {"egl", "osmesa"}, optional
        Force an off-screen OpenGL window kind.
    onscreen : bool
        Draw into a window on the display instead (for live viewers; needs a display).
    light_kit : bool
        Light the scene with VTK's light kit (key, fill, back and head lights, the default);
        without it only the lights of :meth:`add_light` shine.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.render import SurfaceRenderer
    >>> square = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], float)
    >>> with SurfaceRenderer(80, 60, camera="front") as r:
    ...     h = r.add_mesh(square, [[0, 2, 1], [0, 3, 2]], color=(0.9, 0.5, 0.2))
    ...     first = r.render()
    ...     r.update(h, square + (0.2, 0.0, 0.0))
    ...     second = r.render()
    >>> first.shape, first.dtype, bool((first != second).any())
    ((60, 80, 3), dtype('uint8'), True)
    """

    def __init__(self, width: int = 640, height: int = 480, camera: "Camera | str | None" = "iso", *,
                 bounds=None, background=(0.10, 0.11, 0.13), background_top=(0.32, 0.36, 0.43),
                 antialias: bool = True, backend: str | None = None, onscreen: bool = False,
                 light_kit: bool = True):
        for name, v in (("width", width), ("height", height)):
            if not isinstance(v, (int, np.integer)) or not 1 <= v <= 16384:
                raise InputError(name, "an integer number of pixels in [1, 16384]", repr(v))
        from vtkmodules.vtkRenderingCore import vtkLightKit, vtkRenderer  # noqa: PLC0415

        self.width, self.height = int(width), int(height)
        self._camera = Camera.coerce(camera)
        self._bounds = None if bounds is None else self._check_bounds(bounds)
        bottom, top = _rgb(background, "background"), _rgb(background_top, "background_top")
        if onscreen:
            require_display()
            self._window = new_onscreen_window(self.width, self.height)
            self.backend = "onscreen"
        else:
            self._window = new_offscreen_window(self.width, self.height, backend)
            self.backend = offscreen_backend(backend)
        self._renderer = vtkRenderer()
        self._renderer.SetBackground(*bottom)
        self._renderer.SetBackground2(*top)
        self._renderer.SetGradientBackground(bottom != top)
        self._renderer.SetTwoSidedLighting(True)  # cloth is seen from both sides
        # FXAA's post pass leaves an on-screen window's back buffer unreadable (blank grabs).
        self._renderer.SetUseFXAA(bool(antialias) and not onscreen)
        if light_kit:
            vtkLightKit().AddLightsToRenderer(self._renderer)
        else:
            self._renderer.AutomaticLightCreationOff()
        self._window.AddRenderer(self._renderer)
        self._opened()
        self._items: list[_Item] = []
        self._camera_pending = True

    # ----------------------------------------------------------------- scene
    def add_mesh(self, vertices, triangles, color=(0.8, 0.8, 0.8), opacity: float = 1.0, *,
                 feature_angle: float | None = 60.0) -> int:
        """Add a triangle surface; returns its handle for :meth:`update`.

        Parameters
        ----------
        vertices : array_like, shape [vertex_count, 3] [m]
        triangles : array_like of int, shape [triangle_count, 3]
            Vertex indices, counter-clockwise seen from the outside (the lit side; both
            sides are lit, but normals follow this winding).
        color : tuple of 3 float
            RGB in [0, 1].
        opacity : float
            In (0, 1]; below 1 the surface is drawn translucent (depth peeling).
        feature_angle : float or None [degrees]
            Edges sharper than this are shaded as creases (a box's edges); ``None`` smooths
            over every edge.

        Returns
        -------
        int
            Handle of the surface.
        """
        from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray  # noqa: PLC0415
        from vtkmodules.vtkCommonCore import vtkPoints  # noqa: PLC0415
        from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData  # noqa: PLC0415
        from vtkmodules.vtkFiltersCore import vtkPolyDataNormals  # noqa: PLC0415
        from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper  # noqa: PLC0415

        self._check_open()
        x = self._check_vertices(vertices, None, "vertices")
        t = np.asarray(triangles)
        if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] == 0 or not np.issubdtype(t.dtype, np.integer):
            raise InputError("triangles", "an integer array [triangle_count >= 1, 3]", f"shape {t.shape}, dtype {t.dtype}")
        if t.min() < 0 or t.max() >= len(x):
            raise InputError("triangles", f"vertex indices in [0, {len(x) - 1}]", f"range {t.min()}..{t.max()}")
        opacity = float(opacity)
        if not 0 < opacity <= 1:
            raise InputError("opacity", "a number in (0, 1]", repr(opacity))
        array = np.ascontiguousarray(x, dtype=np.float64)  # VTK reads this buffer in place
        points = vtkPoints()
        points.SetData(numpy_to_vtk(array, deep=False))
        cells = vtkCellArray()
        offsets = np.arange(0, 3 * len(t) + 1, 3, dtype=np.int64)
        cells.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
                      numpy_to_vtkIdTypeArray(np.ascontiguousarray(t.ravel(), dtype=np.int64), deep=True))
        poly = vtkPolyData()
        poly.SetPoints(points)
        poly.SetPolys(cells)
        normals = vtkPolyDataNormals()
        normals.SetInputData(poly)
        normals.ComputePointNormalsOn()
        normals.ComputeCellNormalsOff()
        normals.ConsistencyOff()  # keep the caller's winding: FEM surfaces are outward already
        normals.AutoOrientNormalsOff()
        if feature_angle is None:
            normals.SplittingOff()
        else:
            normals.SplittingOn()
            normals.SetFeatureAngle(float(feature_angle))
        mapper = vtkPolyDataMapper()
        mapper.SetInputConnection(normals.GetOutputPort())
        mapper.ScalarVisibilityOff()
        actor = vtkActor()
        actor.SetMapper(mapper)
        self._style(actor, _rgb(color, "color"), opacity)
        used = np.unique(t)
        return self._add(_Item("mesh", actor, points, poly, array, None if len(used) == len(x) else used))

    def add_plane(self, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), size: float = 4.0,
                  color=(0.55, 0.57, 0.6), *, tiles: int = 8) -> int:
        """Add a square ground quad of side ``size`` [m] centred at ``point``, facing ``normal``.

        With ``tiles > 1`` it is a ``tiles`` x ``tiles`` checkerboard of ``color`` and a
        darker shade of it, so that motion over it is visible. It is drawn behind what lies on
        it (:data:`PLANE_DEPTH_OFFSET`). Returns its handle.
        """
        from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray  # noqa: PLC0415
        from vtkmodules.vtkCommonCore import vtkPoints  # noqa: PLC0415
        from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData  # noqa: PLC0415
        from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper  # noqa: PLC0415

        self._check_open()
        p = _vec3(point, "point", "m")
        n = _vec3(normal, "normal", "unit-free")
        if np.linalg.norm(n) == 0:
            raise InputError("normal", "a non-zero vector", repr(normal))
        n = n / np.linalg.norm(n)
        size = _positive(size, "size", "m")
        if not isinstance(tiles, (int, np.integer)) or tiles < 1:
            raise InputError("tiles", "an integer >= 1", repr(tiles))
        rgb = np.asarray(_rgb(color, "color"))
        helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(n, helper)
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        s = np.linspace(-size / 2, size / 2, tiles + 1)
        a, b = np.meshgrid(s, s, indexing="ij")
        xyz = p + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
        i, j = (g.ravel() for g in np.meshgrid(np.arange(tiles), np.arange(tiles), indexing="ij"))
        k = tiles + 1
        quads = np.stack([i * k + j, (i + 1) * k + j, (i + 1) * k + j + 1, i * k + j + 1], axis=1)
        shade = np.where(((i + j) % 2 == 0)[:, None], rgb, 0.8 * rgb)
        points = vtkPoints()
        points.SetData(numpy_to_vtk(np.ascontiguousarray(xyz), deep=True))
        cells = vtkCellArray()
        cells.SetData(numpy_to_vtkIdTypeArray(np.arange(0, 4 * len(quads) + 1, 4, dtype=np.int64), deep=True),
                      numpy_to_vtkIdTypeArray(quads.ravel().astype(np.int64), deep=True))
        poly = vtkPolyData()
        poly.SetPoints(points)
        poly.SetPolys(cells)
        normals = numpy_to_vtk(np.ascontiguousarray(np.broadcast_to(n, xyz.shape)), deep=True)
        normals.SetName("Normals")
        poly.GetPointData().SetNormals(normals)
        colors = numpy_to_vtk(np.ascontiguousarray((shade * 255).round().astype(np.uint8)), deep=True)
        colors.SetName("Colors")
        poly.GetCellData().SetScalars(colors)
        mapper = vtkPolyDataMapper()
        mapper.SetInputData(poly)
        mapper.SetScalarModeToUseCellData()
        mapper.SetColorModeToDirectScalars()
        mapper.ScalarVisibilityOn()
        # VTK applies a mapper's own offset only in polygon-offset mode, a process-wide switch
        # (off by default). Its shared offsets leave other surfaces where they are (0, 0) and
        # bring lines and points a few depth steps forward (the viewer's edge overlays: over
        # the faces they outline rather than half hidden in them).
        mapper.SetResolveCoincidentTopologyToPolygonOffset()
        mapper.SetRelativeCoincidentTopologyPolygonOffsetParameters(*PLANE_DEPTH_OFFSET)
        actor = vtkActor()
        actor.SetMapper(mapper)
        self._style(actor, tuple(rgb), 1.0, specular=0.05)
        return self._add(_Item("plane", actor))

    def add_sphere(self, center, radius: float, color=(0.75, 0.75, 0.78), opacity: float = 1.0) -> int:
        """Add a (static) sphere of ``radius`` [m] at ``center`` [m]; returns its handle."""
        from vtkmodules.vtkFiltersSources import vtkSphereSource  # noqa: PLC0415
        from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper  # noqa: PLC0415

        self._check_open()
        c = _vec3(center, "center", "m")
        radius = _positive(radius, "radius", "m")
        opacity = float(opacity)
        if not 0 < opacity <= 1:
            raise InputError("opacity", "a number in (0, 1]", repr(opacity))
        source = vtkSphereSource()
        source.SetCenter(*c)
        source.SetRadius(radius)
        source.SetThetaResolution(64)
        source.SetPhiResolution(48)
        mapper = vtkPolyDataMapper()
        mapper.SetInputConnection(source.GetOutputPort())
        actor = vtkActor()
        actor.SetMapper(mapper)
        self._style(actor, _rgb(color, "color"), opacity)
        return self._add(_Item("sphere", actor))

    def add_volume(self, volume, preset="ct", sample_distance: float | None = None, mapper: str = "auto") -> int:
        """Add a volume (a CT), drawn with the surfaces; returns its handle for :meth:`update_volume`.

        The volume is ray cast in software and composited by depth with the surfaces: rays
        stop at the opaque surfaces, so a surface in front of the volume hides it and the
        volume hides what lies behind it.

        Parameters
        ----------
        volume : softvr.volume.Volume
            Voxels ``data`` [nx, ny, nz] (at least 2 along each axis) placed by ``spacing``
            [3], ``origin`` [3] and ``direction`` [3, 3], in the world units of the surfaces
            [m].
        preset : str or Preset
            Transfer function: a name from :data:`softvr.render.PRESETS` (``"ct"``: soft
            tissue faint, bone opaque; ``"ct-skin"``: the skin as an opaque surface; ``"mri"``,
            ``"labels"``, ``"auto"``) or a :class:`~softvr.render.Preset`.
        sample_distance : float [voxels], optional
            Ray step in units of the smallest voxel spacing; default 0.5 with ``"warp"`` (a
            structure a voxel thin, such as a CT's headrest, is then met by every ray, not by
            one in two), 1.0 with ``"cpu"`` (VTK's caster takes ~1 s a frame at that already).
        mapper : {"auto", "warp", "cpu"}
            ``"warp"``: softvr's :class:`~softvr.render.RayCaster` (jittered ray starts: a
            thin or flat structure shows fine noise, not the moire and wood grain of rays
            sampled in step; lit by a head light), over the surfaces' colour and depth.
            ``"cpu"``: VTK's ``vtkFixedPointVolumeRayCastMapper`` (lit by the scene's lights;
            labels need it). ``"auto"``: ``"warp"`` off-screen for a continuous transfer
            function, else ``"cpu"`` (an on-screen window shows what VTK draws).

        Returns
        -------
        int
            Handle of the volume. Its bounds count for the camera fit like a mesh's.
        """
        self._check_open()
        if mapper not in ("auto", "warp", "cpu"):
            raise InputError("mapper", "'auto', 'warp' or 'cpu'", repr(mapper))
        if mapper == "auto":
            continuous = not resolve_preset(preset, volume).categorical
            mapper = "warp" if continuous and self.backend != "onscreen" else "cpu"
        if mapper == "warp" and self.backend == "onscreen":
            raise InputError("mapper", "'cpu' or 'auto' in an on-screen window (it shows what VTK draws)", "'warp'")
        default = 0.5 if mapper == "warp" else 1.0
        sample_distance = _positive(default if sample_distance is None else sample_distance, "sample_distance",
                                    "voxels")
        scene = _CastVolume(preset, sample_distance) if mapper == "warp" else VolumeScene(preset, "cpu",
                                                                                          sample_distance)
        scene.update(volume)
        return self._add(_Item("volume", scene.prop, scene=scene))

    def update_volume(self, handle: int, volume, *, changed=True) -> None:
        """Show ``volume`` (any shape, spacing, origin, direction; see :meth:`add_volume`) in
        volume ``handle`` from the next render on. The camera stays where it is (see
        :meth:`reset_camera`).

        ``changed`` (the Warp mapper only): which of its voxels differ from the last update's:
        True (all), False (none) or the inclusive index box ``(lo, hi)``, so that the next
        render casts again only the rays that can see them or a moved surface
        (:meth:`~softvr.render.RayCaster.cast`)."""
        self._check_open()
        item = self._item(handle)
        if item.kind != "volume":
            raise InputError("handle", "the handle of a volume (add_volume)", f"a {item.kind}")
        if isinstance(item.scene, _CastVolume):
            item.scene.update(volume, changed)
        else:
            item.scene.update(volume)

    def ray_caster(self, handle: int) -> RayCaster | None:
        """The :class:`~softvr.render.RayCaster` of volume ``handle`` (None with VTK's mapper),
        e.g. for :attr:`~softvr.render.RayCaster.cast_pixels`."""
        item = self._item(handle)
        if item.kind != "volume":
            raise InputError("handle", "the handle of a volume (add_volume)", f"a {item.kind}")
        return item.scene.caster if isinstance(item.scene, _CastVolume) else None

    def update(self, handle: int, vertices) -> None:
        """New vertex positions [vertex_count, 3] [m] of mesh ``handle`` (same topology)."""
        self._check_open()
        item = self._item(handle)
        if item.kind == "volume":
            raise InputError("handle", "the handle of a mesh (add_mesh); a volume changes with update_volume",
                             "a volume")
        if item.kind != "mesh":
            raise InputError("handle", "the handle of a mesh (add_mesh)", f"a {item.kind}")
        item.array[:] = self._check_vertices(vertices, len(item.array), "vertices")
        item.points.GetData().Modified()
        item.points.Modified()
        item.polydata.Modified()

    def set_color(self, handle: int, color, opacity: float | None = None) -> None:
        """Change the colour (and opacity) of a mesh or sphere (a plane keeps its checkerboard)."""
        item = self._item(handle)
        if item.kind == "volume":
            raise InputError("handle", "the handle of a mesh, sphere or plane (a volume's colours are its preset)",
                             "a volume")
        prop = item.actor.GetProperty()
        prop.SetColor(*_rgb(color, "color"))
        if opacity is not None:
            if not 0 < float(opacity) <= 1:
                raise InputError("opacity", "a number in (0, 1]", repr(opacity))
            prop.SetOpacity(float(opacity))
            self._update_translucency()

    def add_light(self, position, focal_point=(0.0, 0.0, 0.0), color=(1.0, 1.0, 1.0), intensity: float = 1.0) -> None:
        """Add a directional light shining from ``position`` [3] [m] towards ``focal_point``
        [3] [m], of ``color`` (r, g, b in [0, 1]) and ``intensity`` (1: full), fixed in the
        scene (it does not follow the camera)."""
        from vtkmodules.vtkRenderingCore import vtkLight  # noqa: PLC0415

        p, f = _vec3(position, "position", "m"), _vec3(focal_point, "focal_point", "m")
        if np.allclose(p, f):
            raise InputError("position", "a point other than focal_point (the light's direction)", repr(p.tolist()))
        if not (isinstance(intensity, (int, float)) and np.isfinite(intensity) and intensity >= 0):
            raise InputError("intensity", "a number >= 0", repr(intensity))
        light = vtkLight()
        light.SetLightTypeToSceneLight()
        light.SetPositional(False)
        light.SetPosition(*p)
        light.SetFocalPoint(*f)
        light.SetColor(*_rgb(color, "color"))
        light.SetIntensity(float(intensity))
        self._renderer.AddLight(light)

    def handles(self, kind: str | None = None) -> list[int]:
        """Handles of the items added so far, or of those of one ``kind`` ("mesh", "plane",
        "sphere", "volume")."""
        return [h for h, item in enumerate(self._items) if kind is None or item.kind == kind]

    def set_visible(self, handle: int, visible: bool) -> None:
        """Show or hide a surface or volume (a hidden one does not count for the camera fit)."""
        self._item(handle).actor.SetVisibility(bool(visible))

    # ---------------------------------------------------------------- camera
    def set_camera(self, camera: "Camera | str | None" = None, *, bounds=None, **changes) -> None:
        """Use ``camera`` (default: the current one) with ``changes``, fitted to ``bounds``
        (default: as in the constructor), from the next render on."""
        cam = Camera.coerce(camera) if camera is not None else self._camera
        self._camera = cam.with_(**changes) if changes else cam
        if bounds is not None:
            self._bounds = self._check_bounds(bounds)
        self._camera_pending = True

    def set_view(self, eye, forward, up, projection) -> None:
        """An explicit camera from the next render on (a CAVE screen's off-axis frustum): at
        ``eye`` [3] [m] looking along ``forward`` with ``up``, and the 4x4 OpenGL
        ``projection`` as is. :meth:`set_camera` / :meth:`reset_camera` return to the fitted
        camera."""
        from vtkmodules.vtkCommonMath import vtkMatrix4x4  # noqa: PLC0415

        eye, forward = np.asarray(eye, float), np.asarray(forward, float)
        p = np.asarray(projection, float)
        if p.shape != (4, 4) or not np.isfinite(p).all():
            raise InputError("projection", "a finite 4x4 matrix", f"shape {p.shape}")
        cam = self.vtk_camera
        cam.SetPosition(*eye)
        cam.SetFocalPoint(*(eye + forward))
        cam.SetViewUp(*np.asarray(up, float))
        matrix = vtkMatrix4x4()
        for i in range(4):
            for j in range(4):
                matrix.SetElement(i, j, p[i, j])
        cam.SetExplicitProjectionTransformMatrix(matrix)
        cam.UseExplicitProjectionTransformMatrixOn()
        self._camera_pending = False

    def reset_camera(self) -> None:
        """Refit the camera at the next render (to the surfaces as they are then)."""
        self._camera_pending = True

    def scene_bounds(self) -> np.ndarray:
        """(xmin, xmax, ymin, ymax, zmin, zmax) [m] the camera is fitted to."""
        if self._bounds is not None:
            return self._bounds.copy()
        shown = [it for it in self._items if it.actor.GetVisibility()]
        pick = [it for it in shown if it.kind != "plane"] or shown
        if not pick:
            return np.array([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0])
        b = np.array([it.bounds() for it in pick]).reshape(-1, 3, 2)
        return np.stack([b[:, :, 0].min(axis=0), b[:, :, 1].max(axis=0)], axis=1).ravel()

    # ---------------------------------------------------------------- render
    def render(self) -> np.ndarray:
        """Draw the scene; returns RGB uint8 [height, width, 3], row 0 at the top."""
        self._check_open()
        cast = [it.scene for it in self._items if isinstance(it.scene, _CastVolume) and it.actor.GetVisibility()]
        if not cast:
            return self._draw(self.scene_bounds)
        self._apply_camera(self.scene_bounds)
        image = self._cast_over_surfaces([(c.caster, c.volume, c.changed) for c in cast])
        for c in cast:
            c.changed = False
        return image

    # --------------------------------------------------------------- helpers
    def _add(self, item: _Item) -> int:
        if isinstance(item.scene, VolumeScene):
            self._renderer.AddVolume(item.actor)
        else:
            self._renderer.AddActor(item.actor)
        self._items.append(item)
        self._update_translucency()
        return len(self._items) - 1

    def _item(self, handle) -> _Item:
        if not isinstance(handle, (int, np.integer)) or not 0 <= handle < len(self._items):
            raise InputError("handle", f"a handle returned by this renderer (0..{len(self._items) - 1})", repr(handle))
        return self._items[int(handle)]

    def _update_translucency(self) -> None:
        translucent = any(it.actor.GetProperty().GetOpacity() < 1 for it in self._items if it.kind != "volume")
        self._renderer.SetUseDepthPeeling(translucent)

    @staticmethod
    def _style(actor, color, opacity: float, specular: float = 0.35) -> None:
        prop = actor.GetProperty()
        prop.SetColor(*color)
        prop.SetOpacity(opacity)
        prop.SetInterpolationToPhong()
        prop.SetAmbient(0.12)
        prop.SetDiffuse(0.85)
        prop.SetSpecular(specular)
        prop.SetSpecularPower(30.0)

    def _check_open(self) -> None:
        if self._closed:
            raise InputError("SurfaceRenderer", "an open renderer", "a closed one")

    @staticmethod
    def _check_vertices(vertices, count: int | None, what: str) -> np.ndarray:
        x = np.asarray(vertices, dtype=np.float64)
        expected = f"an array [{count if count is not None else 'vertex_count >= 3'}, 3] [m]"
        if x.ndim != 2 or x.shape[1] != 3 or (count is not None and len(x) != count) or len(x) < 3:
            raise InputError(what, expected, f"shape {x.shape}")
        if not np.isfinite(x).all():
            n = int(np.argmax(~np.isfinite(x).all(axis=1)))
            raise InputError(f"{what}[{n}]", "finite coordinates", repr(x[n].tolist()))
        return x

    @staticmethod
    def _check_bounds(bounds) -> np.ndarray:
        b = np.asarray(bounds, float).reshape(-1)
        if b.shape != (6,) or not np.isfinite(b).all() or (b[1::2] < b[::2]).any():
            raise InputError("bounds", "(xmin, xmax, ymin, ymax, zmin, zmax) with min <= max [m]", repr(bounds))
        return b
