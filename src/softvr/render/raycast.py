"""A volume ray caster in Warp that draws into a VTK frame with correct depth.

:class:`RayCaster` casts one ray per pixel through a :class:`~softvr.volume.Volume` with a
:class:`~softvr.render.Preset`'s transfer function: trilinear samples every
``sample_distance`` of the smallest voxel spacing, gradient (Phong) shading and gradient
opacity from central differences computed on the fly (nothing per data change), empty-space
skipping over a min/max grid of bricks (re-derived only where the data changed), early ray
termination, and ray starts jittered per pixel (a hash of the pixel) so that a flat
surface shows fine noise instead of wood-grain bands. From frame to frame (same camera) only
the rays that can see a change are cast again: those through the surfaces' changed pixels and
those whose samples, up to where the ray stopped, come near the voxels that changed. Rays stop
at the depth of the opaque surfaces VTK drew (OpenGL depth buffer) and the volume is blended
over their colour. The kernels are one Warp source for CPU and CUDA; on the CPU their hot loops
run as C++ forms that give the same results bit for bit (``native``; tests compare the two).
:class:`~softvr.render.VolumeRenderer` uses it with ``mapper="warp"``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from softvr.device import blocked_launch, launch, load_kernels, resolve_device
from softvr.errors import InputError
from softvr.render import _raycast_kernels as K
from softvr.render._scene import check_volume
from softvr.render.presets import Preset

__all__ = ["BRICK", "LUT_SIZE", "REACH", "THICK_SLICES", "RayCaster", "transfer_tables", "volume_bounds"]

#: Voxels per brick edge of the empty-space-skipping grid.
BRICK = int(K.BRICK)
#: Bricks a ray may skip at once along each axis (the cap of the brick distance field, < 255).
#: Each flip of a brick's occupancy redoes the field up to REACH - 1 bricks around it: 16 cost
#: the palpation frame ~7 ms CPU in distance passes, 8 ~4 ms, and the rays no more (the head
#: CT's air in front of the face is a few jumps of 8 bricks either way).
REACH = 8
#: Spacing ratio (largest / smallest) from which ``smooth_slices="auto"`` smooths the shading
#: across slices: the head CT's 1.5 mm slices over 0.96 mm pixels (1.57) show a band per slice.
THICK_SLICES = 1.25
#: Entries of the colour/opacity table over the preset's value range.
LUT_SIZE = 4096
#: Cap [bricks] of the distance to the bricks that may read a changed voxel (the stale-ray walk's jumps).
_READ_REACH = 4
_GRADIENT_LUT_SIZE = 256
_ROWS_PER_CHUNK = 8
#: Fewest pixels per thread-pool chunk of the stale-ray test (smaller chunks cost more to hand out).
_STALE_CHUNK = 4096
#: Fewest bricks per chunk of a brick kernel: a small launch runs faster on one thread than split.
_BRICK_CHUNK = 4096
#: Fewest marked bricks per chunk of the launch that marks the pixels their rays cross.
_MARK_CHUNK = 512


def volume_bounds(volume) -> tuple[float, ...]:
    """World bounds (xmin, xmax, ymin, ymax, zmin, zmax) of the voxel centres of ``volume``."""
    n = np.asarray(np.shape(volume.data), float) - 1.0
    corners = np.array([[i, j, k] for i in (0, n[0]) for j in (0, n[1]) for k in (0, n[2])])
    world = np.asarray(volume.origin, float) + (corners * np.asarray(volume.spacing, float)) @ np.asarray(
        volume.direction, float).T
    return tuple(np.ravel(np.column_stack([world.min(axis=0), world.max(axis=0)])))


def transfer_tables(preset: Preset, step_fraction: float) -> dict:
    """The lookup tables of ``preset`` for a ray step of ``step_fraction`` opacity unit lengths.

    Parameters
    ----------
    preset : Preset
        A non-categorical transfer function.
    step_fraction : float
        Ray step / scalar-opacity unit distance (VTK's convention: opacities are per unit).

    Returns
    -------
    dict
        ``rgba`` [LUT_SIZE, 4] float32: colour and step-corrected opacity
        ``1 - (1 - a) ** step_fraction``, sampled linearly over [``lo``, ``hi``] [value units]
        (constant outside, like VTK's clamped tables); ``visible`` [LUT_SIZE + 1] int32: running
        count of entries with opacity > 0; ``gradient`` [256] float32: gradient-opacity factor
        over [0, ``gradient_hi``] [value units per voxel], or None.
    """
    if preset.categorical:
        raise InputError("preset", "a continuous transfer function for the Warp ray caster (labels: mapper='cpu')",
                         repr(preset.name))
    points = [p[0] for p in preset.colors] + [p[0] for p in preset.opacities]
    lo, hi = float(min(points)), float(max(points))
    hi = hi if hi > lo else lo + 1.0
    values = np.linspace(lo, hi, LUT_SIZE)
    c = np.asarray(preset.colors, float)
    o = np.asarray(preset.opacities, float)
    rgba = np.empty((LUT_SIZE, 4), np.float32)
    for ch in range(3):
        rgba[:, ch] = np.interp(values, c[:, 0], c[:, ch + 1])
    rgba[:, 3] = 1.0 - (1.0 - np.interp(values, o[:, 0], o[:, 1])) ** step_fraction
    visible = np.concatenate([[0], np.cumsum(rgba[:, 3] > 0)]).astype(np.int32)
    out = {"rgba": rgba, "lo": lo, "hi": hi, "visible": visible, "gradient": None, "gradient_hi": 0.0}
    if preset.gradient_opacities:
        g = np.asarray(preset.gradient_opacities, float)
        g_hi = float(g[:, 0].max()) if g[:, 0].max() > 0 else 1.0
        out["gradient"] = np.interp(np.linspace(0.0, g_hi, _GRADIENT_LUT_SIZE), g[:, 0], g[:, 1]).astype(np.float32)
        out["gradient_hi"] = g_hi
    return out


class RayCaster:
    """Ray cast volumes into RGB frames (module docstring); one instance per view.

    Parameters
    ----------
    preset : Preset
        Transfer function (not categorical).
    sample_distance : float [voxels]
        Ray step in units of the smallest voxel spacing (also the opacity unit length).
    jitter : bool
        Offset each pixel's samples by a per-pixel fraction of a step (no banding).
    smooth_slices : {"auto", True, False}
        Shade with the gradient smoothed across slices (weights 1, 2, 1 over neighbouring
        slices, along the axis of the largest spacing): a surface almost parallel to thick
        slices (a skull's top on a CT of 1.5 mm slices) is otherwise drawn in bands, one per
        slice. ``"auto"``: where that spacing is at least ``THICK_SLICES`` times the smallest.
        Shaded samples then take three gradients instead of one.
    device : str, optional
        Warp device (default: CUDA when present, else CPU).
    native : bool
        On the CPU, run the kernels' C++ forms (the same results bit for bit, ~2x less CPU for
        the brick updates, ~1.2x for the rays); False: Warp's code, the reference (as on CUDA).
        An attribute too, read at each :meth:`cast`.
    """

    def __init__(self, preset: Preset, sample_distance: float = 0.5, *, jitter: bool = True,
                 smooth_slices: "str | bool" = "auto", device: str | None = None, native: bool = True):
        if not sample_distance > 0:
            raise InputError("sample_distance", "a number > 0 [voxels]", repr(sample_distance))
        if smooth_slices not in ("auto", True, False):
            raise InputError("smooth_slices", "'auto', True or False", repr(smooth_slices))
        self.device = resolve_device(device)
        self.sample_distance = float(sample_distance)
        self.jitter = bool(jitter)
        self.smooth_slices = smooth_slices
        self.preset = preset
        self.native = bool(native)
        self._tables_key: tuple | None = None
        self._grid_key: tuple | None = None
        self._vol: wp.array | None = None
        self._known: wp.array | None = None  # the voxels as last uploaded (if kept), to find the bricks that changed
        self._flips: list = []  # brick boxes whose occupancy flipped since the last cast
        self._view_key: tuple | None = None  # what the per-pixel state below was cast for
        #: Pixels [count] cast by the last :meth:`cast` (the others kept their colour).
        self.cast_pixels = 0
        load_kernels(K.raycast, self.device)

    def reset(self) -> None:
        """Forget everything kept from frame to frame (brick grid, tables, rays' state): the
        next :meth:`cast` starts from scratch, as a new caster's would."""
        self._tables_key = self._grid_key = self._view_key = None
        self._flips = []

    # --------------------------------------------------------------- data
    def _upload(self, volume, changed) -> None:
        """Take ``volume``'s voxels and bring the brick grid up to date: ranges and occupancy
        of the bricks touching the ``changed`` index box, distances within ``REACH`` of them
        (everything when the grid or the transfer function is new)."""
        data = check_volume(volume)
        name = data.dtype.name if data.dtype.name in K.VOXEL_TYPES else "float32"
        if data.dtype.name != name:
            data = data.astype(np.float32)
        shape = data.shape
        dev = self.device
        self._voxel_type = name
        if not (data.flags.c_contiguous or data.flags.f_contiguous):
            data = np.ascontiguousarray(data)
        # A flat view in memory order and the element strides of the three axes.
        strides = tuple(st // data.itemsize for st in data.strides)
        self._strides = wp.vec3i(*strides)
        flat = data.ravel(order="K")
        if dev == "cpu":
            self._vol = wp.array(flat, dtype=K.VOXEL_TYPES[name], device=dev, copy=False)
            self._keep = flat  # the memory Warp reads
        else:
            self._vol = wp.array(flat, dtype=K.VOXEL_TYPES[name], device=dev)
        self._vol_ptr = self._vol.ptr  # the voxels' address for the kernels' C++ forms
        nb = np.asarray([-(-(s - 1) // BRICK) for s in shape])
        retabled = self._tables(volume)
        fresh = retabled or (shape, name) != self._grid_key
        if (shape, name) != self._grid_key:
            # The distance field's seed and passes are kept: an update redoes them near the change only.
            self._pass1, self._pass2, self._distance = (wp.empty(tuple(nb), dtype=wp.uint8, device=dev) for _ in range(3))
            self._seed = wp.full(tuple(nb), 255, dtype=wp.uint8, device=dev)  # no seed value: all written
            self._cells = wp.empty(tuple(nb), dtype=wp.uint64, device=dev)
            self._grid_key = (shape, name)
            changed = True
        # Bricks whose own voxels changed since the last upload (all written in the changed box).
        self._changed_bricks = wp.zeros(tuple(nb), dtype=wp.uint8, device=dev)
        # Bricks that turned occupied or whose cells' masks gained a bit since the last cast (raycast's read_from).
        self._gained = wp.zeros(tuple(nb), dtype=wp.uint8, device=dev)
        self._changed_box: tuple | None = None
        if changed is True:
            first, last = np.zeros(3, int), nb - 1
            self._known = None  # copied at the next partial change only: a caller that changes all pays nothing
        elif changed is None or changed is False:
            first, last = np.zeros(3, int), -np.ones(3, int)
        else:
            lo, hi = (np.asarray(c, int) for c in changed)
            # Voxel v is owned by brick min(v // BRICK, nb - 1) (brick_changes).
            owners = np.clip(lo // BRICK, 0, nb - 1), np.clip(hi // BRICK, 0, nb - 1)
            if self._known is None:  # the voxels before this change are gone: all in the box count as changed
                self._known = wp.clone(self._vol)
                self._changed_bricks.fill_(1)
            else:
                self._run(K.BRICK_CHANGES[name], *owners, [self._vol, wp.vec3i(*shape), self._strides],
                          [self._known, *self._packed_rows(flat, strides), self._changed_bricks], blocked=True)
            self._changed_box = owners
            # Occupancy before this change: a sample in a brick empty before and after it is
            # transparent in both frames, whatever it reads (:meth:`_read_distance`).
            self._occupied_before = self._seed.numpy() == 0
            # Brick b reads voxels b*BRICK .. (b+1)*BRICK: voxel v is read by bricks (v-1)//BRICK .. v//BRICK.
            first, last = np.clip((lo - 1) // BRICK, 0, nb - 1), np.clip(hi // BRICK, 0, nb - 1)
        if retabled:  # the cells' masks and the occupancy depend on the table
            first, last = np.zeros(3, int), nb - 1
        if np.all(last >= first):
            count = last - first + 1
            flips: wp.array = wp.zeros(int(np.prod(count)), dtype=wp.uint8, device=dev)
            # On the CPU in C++ (the Warp code's integers and bits, see brick_minmax), reading the voxels in place.
            code = self._voxel_code()
            self._run(K.BRICK_MINMAX[name], first, last,
                      [self._vol, wp.vec3i(*shape), self._strides, self._changed_bricks,
                       int(changed is True or retabled), self._visible, float(self._lut_lo), float(self._lut_scale),
                       REACH, wp.uint64(self._vol_ptr), code],
                      [self._seed, flips, self._cells, self._gained], blocked=True)
            flipped = np.flatnonzero(flips.numpy())
            if not len(flipped):
                return
            at = np.column_stack(np.unravel_index(flipped, tuple(count))) + first  # brick_of's order
            box = np.concatenate([at.min(axis=0), at.max(axis=0)])
            # The rays' empty prefixes must be re-checked against the flipped bricks
            # [index coordinates covered: b * BRICK .. (b + 1) * BRICK].
            self._flips.append((box[:3] * BRICK, (box[3:] + 1) * BRICK))
            if not fresh:  # redo the distances only around the bricks that turned empty or occupied
                first, last = box[:3].astype(int), box[3:].astype(int)
            self._distance_passes(first, last, [self._seed, self._pass1, self._pass2, self._distance], REACH)

    def _voxel_code(self) -> int:
        """The voxels' code for the kernels' C++ forms (``NATIVE_VOXEL_CODES``), 0 where they run
        Warp's code: on CUDA, or with :attr:`native` off."""
        return K.NATIVE_VOXEL_CODES[self._voxel_type] if self.native and self.device == "cpu" else 0

    def _packed_rows(self, flat: np.ndarray, s: tuple) -> list:
        """``brick_changes``' 64-bit views of the voxels ``flat`` (element strides ``s`` [3])
        and of the kept copy, and whether they hold (CPU, 2-byte voxels whose last axis is
        contiguous and a multiple of BRICK long, both arrays 8-byte aligned): one compare per
        inner brick row instead of BRICK."""
        assert self._known is not None  # kept since the last upload
        if (self._voxel_code() and flat.itemsize * BRICK == 8 and s[2] == 1 and s[1] % BRICK == 0
                and s[0] % BRICK == 0 and flat.ctypes.data % 8 == 0 and self._known.ptr % 8 == 0):
            return [wp.array(a.view(np.int64), dtype=wp.int64, device="cpu", copy=False)
                    for a in (flat, self._known.numpy())] + [1]
        none = wp.zeros(1, dtype=wp.int64, device=self.device)
        return [none, none, 0]

    def _distance_passes(self, first, last, fields: list, reach: int) -> None:
        """Bring the distance field ``fields[3]`` (through the passes ``fields[1]``, ``[2]``)
        up to date after its seed ``fields[0]`` changed in the bricks ``first .. last`` [3]."""
        if self._voxel_code():
            launch(K.brick_distance_passes, 1, [*fields, reach, wp.vec3i(*first), wp.vec3i(*last)], "cpu")
            return
        first, last = np.array(first), np.array(last)
        nb = np.asarray(fields[0].shape)
        # A changed seed moves the values of pass ``axis`` up to reach - 1 bricks away along
        # that axis and the axes before it.
        for axis in range(3):
            first[axis], last[axis] = max(first[axis] - reach + 1, 0), min(last[axis] + reach - 1, nb[axis] - 1)
            self._run(K.brick_distance_pass, first, last, [fields[axis], axis, reach], [fields[axis + 1]])

    def _run(self, kernel, first, last, inputs, outputs, *, blocked: bool = False) -> None:
        """Launch a brick kernel over the bricks ``first .. last`` (inclusive) [3] (``blocked``:
        :func:`~softvr.device.blocked_launch`, the kernel's last parameters ``block, offset``)."""
        count = last - first + 1
        run = blocked_launch if blocked else launch
        run(kernel, int(np.prod(count)), [*inputs, wp.vec3i(*first), wp.vec3i(*count), *outputs], self.device,
            min_chunk=_BRICK_CHUNK)

    def _tables(self, volume) -> bool:
        """Build the transfer tables if the preset, step or unit changed; True if rebuilt."""
        unit = float(np.min(volume.spacing))
        key = (self.preset, self.sample_distance, unit)
        if key == self._tables_key:
            return False
        t = transfer_tables(self.preset, self.sample_distance)
        dev = self.device
        self._lut: wp.array = wp.array(t["rgba"], dtype=wp.vec4, device=dev)
        self._visible: wp.array = wp.array(t["visible"], dtype=wp.int32, device=dev)
        self._lut_lo, self._lut_scale = t["lo"], (LUT_SIZE - 1) / (t["hi"] - t["lo"])
        if t["gradient"] is None:
            self._gradient = wp.zeros(2, dtype=float, device=dev)
            self._gradient_scale = -1.0
        else:
            self._gradient = wp.array(t["gradient"], dtype=float, device=dev)
            # Gradient opacity is tabulated per voxel (smallest spacing) of distance.
            self._gradient_scale = unit * (_GRADIENT_LUT_SIZE - 1) / t["gradient_hi"]
        self._tables_key = key
        return True

    # --------------------------------------------------------------- render
    def cast(self, volume, ndc_to_world, light, surface, depth, *, changed=True) -> np.ndarray:
        """Ray cast ``volume`` over a frame of opaque surfaces.

        Parameters
        ----------
        volume : softvr.volume.Volume
            Voxels [nx, ny, nz] with ``spacing`` [world units], ``origin``, ``direction``.
        ndc_to_world : array_like, shape [4, 4]
            Inverse of the camera's world-to-normalized-device matrix (VTK's composite
            projection transform, z in [-1, 1]).
        light : array_like, shape [3]
            Unit direction towards the light [world].
        surface : numpy.ndarray, shape [height, width, 3] or [height, width, 4], uint8
            The surfaces' (and background's) colour, RGB or RGBA (the alpha is not read; an
            RGBA frame's pixels compare with last frame's as 32-bit words), row 0 at the top.
        depth : numpy.ndarray, shape [height, width], float32
            Their OpenGL depth in [0, 1], row 0 at the bottom (1: nothing drawn).
        changed : True, False or (lo, hi)
            What changed in the voxels since the last call: everything, nothing, or only
            the inclusive index box ``lo`` .. ``hi`` [3] + [3] (bricks elsewhere are kept).
            Unless everything changed, a frame with the last one's camera, light, grid and
            table casts only the pixels whose surface colour or depth changed or whose
            samples may read a voxel in the box (:attr:`cast_pixels`); the others keep their
            colour, which a full cast would reproduce bit for bit.

        Returns
        -------
        numpy.ndarray, shape [height, width, 3], uint8
        """
        self._upload(volume, changed)
        height, width = depth.shape
        spacing = np.asarray(volume.spacing, float)
        direction = np.asarray(volume.direction, float)
        index_to_world = np.eye(4)
        index_to_world[:3, :3] = direction * spacing
        index_to_world[:3, 3] = np.asarray(volume.origin, float)
        # d value / d world = D diag(1/s) (d value / d index), D orthonormal.
        gradient_to_world = direction / spacing
        p = self.preset
        dev = self.device
        ndc_to_world = np.asarray(ndc_to_world, float)
        light = np.asarray(light, float)
        # The rays' known-empty prefixes, their sample segments and last frame's colours hold for
        # one camera, light, grid, table and step.
        key = (width, height, ndc_to_world.tobytes(), light.tobytes(), index_to_world.tobytes(), self._grid_key,
               self._tables_key, self.jitter, self.smooth_slices)
        depth_host = np.ascontiguousarray(depth, np.float32)
        surface_host = _rgba(surface)
        # On the CPU the kernels read the host arrays in place (alive until the cast returns).
        in_place = dev == "cpu"
        depth = wp.array(depth_host, dtype=float, device=dev, copy=not in_place)
        # The RGB channels as a view of the RGBA pixels (Warp reads it through its strides).
        rgb = surface_host[:, :, :3]
        surface = wp.array(rgb if in_place else np.ascontiguousarray(rgb), dtype=wp.uint8, device=dev,
                           copy=not in_place)
        # The same for every frame of one view (the spacing and option are in its key).
        self._smoothed = self._smooth_axis(spacing) if p.shade else -1
        flips, self._flips = self._flips, []
        flip_lo = np.min([b[0] for b in flips], axis=0) if flips else np.zeros(3)
        flip_hi = np.max([b[1] for b in flips], axis=0) if flips else np.zeros(3)
        flipped = [len(flips), wp.vec3(*flip_lo), wp.vec3(*flip_hi)]
        if key != self._view_key or changed is True:
            if key != self._view_key:
                self._empty_until = wp.zeros(width * height, dtype=float, device=dev)
                self._read_from = wp.zeros(width * height, dtype=float, device=dev)
                self._image = wp.empty((height, width, 3), dtype=wp.uint8, device=dev)
                self._segments = [wp.empty(width * height, dtype=wp.vec3, device=dev) for _ in range(2)]
                self._rays = [wp.empty(width * height, dtype=t, device=dev)
                              for t in (wp.vec3, wp.vec3, wp.vec3, wp.vec2, wp.vec4)]
                self._every_pixel: wp.array = wp.array(np.arange(width * height, dtype=np.int32), device=dev)
                self._view_key = key
            self._last_depth, self._last_surface = depth_host.copy(), surface_host.copy()
            pixels = self._every_pixel
            store_rays = 1  # every pixel is cast: each ray is worked out and kept for this view
        else:
            store_rays = 0
            pixels = self._stale_pixels(depth_host, surface_host, changed, flipped,
                                        np.linalg.inv(ndc_to_world) @ index_to_world)
        self.cast_pixels = int(pixels.shape[0])
        inputs = [
            self._vol, wp.uint64(self._vol_ptr if self._voxel_code() else 0), self._voxel_code(),
            wp.vec3i(*np.shape(volume.data)), self._strides, wp.mat44(*np.linalg.inv(index_to_world).ravel()),
            wp.mat33(*gradient_to_world.ravel()), wp.mat44(*ndc_to_world.ravel()),
            int(width), int(height), float(self.sample_distance * spacing.min()), int(self.jitter),
            self._lut, float(self._lut_lo), float(self._lut_scale), self._gradient,
            float(self._gradient_scale), wp.vec3(p.ambient, p.diffuse, p.specular),
            wp.vec3(*light), int(bool(p.shade)), self._smoothed, wp.vec3(*direction[:, max(self._smoothed, 0)]),
            self._distance, self._cells,
            *flipped, self._empty_until, self._read_from, self._gained, int(changed is not True),
            depth, surface, pixels,
            self._image, *self._segments, store_rays, *self._rays,
        ]
        blocked_launch(K.RAYCAST[self._voxel_type], self.cast_pixels, inputs, dev, min_chunk=_ROWS_PER_CHUNK * width)
        # A copy: the caster's image is next frame's starting point.
        return self._image.numpy().copy()

    def _smooth_axis(self, spacing: np.ndarray) -> int:
        """The index axis to smooth the shading gradient along (``smooth_slices``), or -1."""
        thick = int(np.argmax(spacing))
        if self.smooth_slices == "auto":
            return thick if spacing[thick] >= THICK_SLICES * spacing.min() else -1
        return thick if self.smooth_slices else -1

    def _read_distance(self) -> tuple[np.ndarray, np.ndarray]:
        """Each brick's Chebyshev distance [bricks] to the nearest one where a ray sample may
        read a voxel that changed and be seen, capped at ``_READ_REACH`` [nb] uint8, and the
        indices [m, 3] of those marked bricks. A sample at p reads voxels floor(p) - 2 ..
        floor(p) + 3 (trilinear weights, central differences, smoothing across slices), so in brick c (p in [c, c + 1) * BRICK,
        BRICK >= 3) it reads voxels of the bricks c - 1 .. c + 1 per axis only. Its own
        corners lie in brick c's range, so where c is empty (no value of non-zero opacity)
        before and after the change the sample is transparent in both frames and what it
        reads does not matter: the marked bricks are the occupied ones (before or after)
        within 1 of a changed brick. In numpy on the changed bricks' box grown by one: a few
        thousand bricks, where a Warp thread per brick costs more on the CPU than the work."""
        nb = np.asarray(self._changed_bricks.shape)
        read = np.full(tuple(nb), _READ_REACH, np.uint8)
        none = np.zeros((0, 3), int)
        if self._changed_box is None:
            return read, none
        # The marked bricks lie within 1 of the changed box, and the stale-ray walk only runs
        # within 1 of it (the rewritten voxels grown by READ_REACH < BRICK): the distances there
        # are exact when the transform sees just that box, which holds every marked brick.
        first = np.maximum(self._changed_box[0] - 1, 0)
        last = np.minimum(self._changed_box[1] + 1, nb - 1)
        box = tuple(slice(a, b + 1) for a, b in zip(first, last))
        changed = self._changed_bricks.numpy()[box] != 0
        if not changed.any():
            return read, none
        marked = _grown(changed) & (self._occupied_before[box] | (self._seed.numpy()[box] == 0))
        if not marked.any():
            return read, none
        # The Chebyshev distance d to the marked bricks, capped: within r of one for r = d .. cap - 1,
        # so cap - (the number of r < cap within r of one) is min(d, cap).
        within, count = marked, marked.astype(np.uint8)
        for _ in range(_READ_REACH - 1):
            within = _grown(within)
            count += within
        read[box] = _READ_REACH - count
        return read, np.argwhere(marked) + first

    def _stale_pixels(self, depth: np.ndarray, surface: np.ndarray, changed, flipped: list,
                      index_to_ndc: np.ndarray) -> wp.array:
        """The pixels [count] int32 to cast again after the last frame (same view): where the
        surfaces' ``depth`` [height, width] or ``surface`` colour [height, width, 4] (RGBA) changed or
        the ray's samples may read a voxel in the ``changed`` box (False or None: no voxel
        changed). The others forget their known-empty prefix if it may cross a brick in the
        ``flipped`` box (count, lo, hi). ``index_to_ndc`` [4, 4] projects the volume's index
        space to the screen."""
        height, width = depth.shape
        # The surface comparison in numpy: a few vector passes, where a Warp thread per pixel
        # costs more on the CPU than the comparison itself.
        moved = surface.view(np.uint32)[..., 0] != self._last_surface.view(np.uint32)[..., 0]
        moved |= (depth != self._last_depth)[::-1]  # depth rows run up
        np.copyto(self._last_depth, depth)
        np.copyto(self._last_surface, surface)
        stale: wp.array = wp.array(moved.ravel(), dtype=wp.bool, device=self.device, copy=self.device != "cpu")
        boxed = not (changed is None or changed is False)
        lo, hi = (np.asarray(c, float) for c in changed) if boxed else (np.zeros(3), np.zeros(3))
        read_host, marked = self._read_distance()
        read: wp.array = wp.array(read_host, dtype=wp.uint8, device=self.device)
        # How far a sample reads: READ_REACH, one voxel more along the axis smoothed across slices.
        reach = np.full(3, float(K.READ_REACH))
        if self._smoothed >= 0:
            reach[self._smoothed] += 1.0
        # Only a ray through a marked brick can be stale: the pixels whose rays meet one, from
        # each brick's projected bounds, are the only ones whose samples are walked; the
        # others in the flipped box only check it.
        candidates: wp.array = wp.zeros(width * height, dtype=wp.uint8, device=self.device)
        rect = (width, -1, height, -1)
        boxes = []  # (lower corners [m, 3], upper corners [m, 3], mark their pixels as candidates?)
        if boxed:
            corner = marked.astype(np.float32) * BRICK
            boxes.append((corner, corner + BRICK, 1))
        if flipped[0]:
            boxes.append((np.array([flipped[1]], np.float32), np.array([flipped[2]], np.float32), 0))
        for corner_lo, corner_hi, mark in boxes:
            if len(corner_lo):
                rects: wp.array = wp.empty(len(corner_lo), dtype=wp.vec4i, device=self.device)
                launch(K.mark_pixels, len(corner_lo),
                       [wp.array(corner_lo, dtype=wp.vec3, device=self.device),
                        wp.array(corner_hi, dtype=wp.vec3, device=self.device), wp.mat44(*index_to_ndc.ravel()),
                        int(width), int(height), mark, int(self._voxel_code() != 0), candidates, rects], self.device,
                       min_chunk=_MARK_CHUNK)
                r = rects.numpy()
                rect = (min(rect[0], int(r[:, 0].min())), max(rect[1], int(r[:, 1].max())),
                        min(rect[2], int(r[:, 2].min())), max(rect[3], int(r[:, 3].max())))
        blocked_launch(K.stale_pixels, max(rect[1] - rect[0] + 1, 0) * max(rect[3] - rect[2] + 1, 0),
                       [int(width), int(boxed), wp.vec3(*lo), wp.vec3(*hi), wp.vec3(*reach), read, candidates,
                        wp.vec4i(*rect), *self._segments, *flipped, self._empty_until, stale], self.device,
                       min_chunk=_STALE_CHUNK)
        return wp.array(np.flatnonzero(stale.numpy()).astype(np.int32), dtype=wp.int32, device=self.device)


def _grown(mask: np.ndarray) -> np.ndarray:
    """``mask`` (3-D bool) grown by one cell in the 26 directions (a chessboard dilation, nothing
    beyond its edges): ``scipy.ndimage.maximum_filter(mask, 3, mode="constant")`` by six slice ORs,
    ~4x faster on the few thousand bricks of a frame (30 against 114 us on 22 x 22 x 30)."""
    out = mask.copy()
    for axis in range(3):
        src = out.copy()
        lead = [slice(None)] * 3
        tail = [slice(None)] * 3
        lead[axis], tail[axis] = slice(1, None), slice(None, -1)
        out[tuple(lead)] |= src[tuple(tail)]
        out[tuple(tail)] |= src[tuple(lead)]
    return out


def _rgba(surface) -> np.ndarray:
    """``surface`` [height, width, 3 or 4] as C-contiguous uint8 RGBA (as it is if it already is;
    an RGB one gets alpha 255)."""
    s = np.asarray(surface)
    if s.ndim != 3 or s.shape[2] not in (3, 4) or s.dtype != np.uint8:
        raise InputError("surface", "an RGB or RGBA image [height, width, 3 or 4] of uint8",
                         f"shape {s.shape}, dtype {s.dtype}")
    if s.shape[2] == 4:
        return np.ascontiguousarray(s)
    out = np.empty(s.shape[:2] + (4,), np.uint8)
    out[:, :, :3] = s
    out[:, :, 3] = 255
    return out
