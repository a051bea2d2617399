"""What runs on every copy of a cluster application: its state, and where the master gets it.

* :class:`ClusterState` — the application state every node holds and the master owns: frame
  number, time, the user entity's pose (world <- tracker), the head pose, flags set by
  events, static items (planes, spheres) and surface meshes with their streamed vertices.
  Nodes apply frames to it deterministically; :meth:`ClusterState.digest` hashes it so that
  copies can be compared frame by frame.
* Items, the drawables as plain data: :func:`mesh_item`, :func:`plane_item`, :func:`sphere_item`
  (one dict each, its index in the list the handle), :func:`scene_bounds`.
* Frame sources for the master: :class:`PlayerSource` (a scene played by its
  :class:`softvr.app.Player`, its :meth:`~softvr.app.Player.drawables` streamed), :class:`SceneFileSource` (a
  static glTF / mesh-file scene) and :class:`WavingSheet` (an analytic deforming sheet for tests
  and the benchmark).
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np

from softvr.app import PLANE_COLOR, PLANE_TILES, SPHERE_COLOR
from softvr.cave.protocol import (MAX_FRAME, MAX_MESHES, MAX_NAME, PacketError, check_head, check_mesh_update,
                                  check_user, decode, encode)
from softvr.cave.rig import UserPose, turn
from softvr.cave.stream import DEFAULT_QUANTUM, MeshDecoder, MeshEncoder
from softvr.errors import InputError
from softvr.files import native_read
from softvr.model.shapes import BOX_TRIANGLES, box_corners

__all__ = ["PLANE_COLOR", "SPHERE_COLOR", "ClusterState", "FrameBuilder", "PlayerSource", "SceneFileSource",
           "WavingSheet", "mesh_item", "plane_item", "scene_bounds", "sphere_item", "user_pose_facing"]

_IDENTITY_HEAD = (0.0, 0.0, 1.7, 1.0, 0.0, 0.0, 0.0)
#: Largest mesh a snapshot may carry [vertices] (its rest shape: 24 bytes each).
MAX_VERTICES = 1 << 22
_MAX_FLAGS = 1024


def mesh_item(vertices, triangles, color=(0.8, 0.8, 0.8), opacity: float = 1.0) -> dict:
    """A triangle mesh item: its ``rest`` vertices [v, 3] [m] (the stream's first state),
    ``faces`` [t, 3] int32, ``color`` (r, g, b) and ``opacity``."""
    return {"kind": "mesh", "rest": np.array(vertices, float), "faces": np.asarray(triangles, np.int32),
            "color": [float(c) for c in color], "opacity": float(opacity)}


def plane_item(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), size: float = 4.0, color=PLANE_COLOR, *,
               tiles: int = 8) -> dict:
    """A static plane item: a square of ``size`` [m] through ``point`` [3] [m], drawn in ``tiles``."""
    return {"kind": "plane", "point": [float(x) for x in point], "normal": [float(x) for x in normal],
            "size": float(size), "color": [float(c) for c in color], "tiles": int(tiles)}


def sphere_item(center, radius: float, color=SPHERE_COLOR, opacity: float = 1.0) -> dict:
    """A static sphere item of ``radius`` [m] at ``center`` [3] [m]."""
    return {"kind": "sphere", "center": [float(x) for x in center], "radius": float(radius),
            "color": [float(c) for c in color], "opacity": float(opacity)}


def scene_bounds(items: list, vertices: dict) -> np.ndarray:
    """(xmin, xmax, ymin, ymax, zmin, zmax) [m] of the meshes' ``vertices`` (handle -> [v, 3]) and
    the spheres of ``items`` (planes are unbounded: left out)."""
    points = list(vertices.values())
    points += [np.asarray(i["center"]) + s * i["radius"] for i in items if i["kind"] == "sphere" for s in (-1, 1)]
    p = np.vstack([np.atleast_2d(x) for x in points]) if points else np.zeros((1, 3))
    return np.stack([p.min(axis=0), p.max(axis=0)], axis=1).ravel()


def user_pose_facing(center, yaw: float = 0.0, *, anchor=(0.0, 1.2, 1.0)) -> np.ndarray:
    """The user pose [4, 4] (world <- tracker) that shows world point ``center`` [3] [m] at
    tracker point ``anchor`` [3] [m] (in front of the viewer, at table height), the CAVE
    turned by ``yaw`` [rad] about the vertical through it."""
    anchor = np.asarray(anchor, float)
    return np.array(turn(UserPose(np.asarray(center, float) - anchor), yaw, about=anchor).matrix)


def _positive(value, what: str, high: float = 1e6) -> float:
    v = float(value)
    if not 0 < v <= high:
        raise PacketError("malformed", f"snapshot {what}: expected a number in (0, {high:g}], found {v!r}")
    return v


def _integer(value, what: str, low: int, high: int) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
        raise PacketError("malformed", f"snapshot {what}: expected an integer in [{low}, {high}], found {value!r:.40}")
    return value


def _check_floats(value, shape, what: str) -> np.ndarray:
    a = np.asarray(value, float) if isinstance(value, list) else None
    if a is None or a.shape != shape or not np.isfinite(a).all():
        raise PacketError("malformed", f"snapshot {what}: expected finite numbers of shape {shape}")
    return a


class ClusterState:
    """The state of a cluster application (module docstring).

    Attributes
    ----------
    n : int
        Frame number (-1 before the first frame).
    t : float [s]
        Application time.
    user : ndarray, shape [4, 4]
        The user entity's pose: world <- tracker frame (navigation moves it).
    head : ndarray, shape [7]
        Head position [m] and orientation quaternion (w, x, y, z) in the tracker frame.
    flags : dict of str -> bool
        Application switches flipped by ``toggle`` events.
    items : list of dict
        Static items (``plane``, ``sphere``) and meshes (:func:`plane_item`, :func:`sphere_item`,
        :func:`mesh_item`); a handle is an index into this list.
    meshes : dict of int -> MeshDecoder
        The streamed vertex state of every mesh item.
    quantum : float [m]
        Vertex quantization step of the stream.
    """

    def __init__(self, items: list, quantum: float = DEFAULT_QUANTUM):
        self.items = items
        self.quantum = float(quantum)
        self.meshes = {h: MeshDecoder(i["rest"], quantum) for h, i in enumerate(items) if i["kind"] == "mesh"}
        self.n, self.t = -1, 0.0
        self.user = np.eye(4)
        self.head = np.array(_IDENTITY_HEAD)
        self.flags: dict[str, bool] = {}
        self._geometry: bytes | None = None

    # ----------------------------------------------------------------- frames
    def apply_frame(self, frame: dict) -> None:
        """Apply a validated ``frame`` payload (frame ``n`` must be ``self.n + 1``). Raises
        ``ValueError`` if a mesh update does not fit this state (the caller resyncs)."""
        for update in frame["meshes"]:
            mesh = self.meshes.get(update[0])
            if mesh is None:
                raise ValueError(f"an update for mesh {update[0]}, which this state does not have")
            mesh.apply(update[1:])
        for name, args in frame["events"]:
            if name == "toggle" and args and isinstance(args[0], str):
                self.flags[args[0]] = not self.flags.get(args[0], False)
        self.n, self.t = frame["n"], frame["t"]
        self.user = np.asarray(frame["user"], float).reshape(4, 4)
        self.head = np.asarray(frame["head"], float)

    def digest(self) -> bytes:
        """16 bytes of the SHA-1 of everything a render depends on (frame, time, poses, flags,
        mesh states): equal digests, equal pictures. (A consistency check between copies, not
        a defence against forgery, which is CURVE's job; SHA-1 hashes the 120 kB of a 10 K-vertex
        mesh twice as fast as BLAKE2b here, with hardware support.)"""
        h = hashlib.sha1()
        h.update(np.array([self.n], np.int64).tobytes() + np.array([self.t], float).tobytes())
        h.update(self.user.tobytes() + self.head.tobytes())
        h.update(repr(sorted(k for k, v in self.flags.items() if v)).encode())  # as a snapshot keeps them
        for handle in sorted(self.meshes):
            h.update(handle.to_bytes(4, "little") + self.meshes[handle].state_bytes())
        return h.digest()[:16]

    def geometry_digest(self) -> bytes:
        """16-byte BLAKE2b of the items' fixed parts (kinds, faces, rest shapes, colours): a
        node keeps its renderer across a resync when this is unchanged."""
        if self._geometry is None:
            h = hashlib.blake2b(digest_size=16)
            for item in self.items:
                for key in sorted(item):
                    value = item[key]
                    fixed = value.tobytes() if isinstance(value, np.ndarray) else repr(value).encode()
                    h.update(key.encode() + fixed)
            self._geometry = h.digest()
        return self._geometry

    def mesh_vertices(self, handle: int) -> np.ndarray:
        """Current vertices [v, 3] [m] of mesh item ``handle``."""
        return self.meshes[handle].vertices()

    # -------------------------------------------------------------- snapshots
    def snapshot(self) -> dict:
        """The whole state as msgpack-ready data (geometry included, so a node needs no scene
        file)."""
        items = []
        for h, item in enumerate(self.items):
            if item["kind"] == "mesh":
                items.append({"kind": "mesh", "rest": item["rest"].astype(float).tobytes(),
                              "faces": item["faces"].astype(np.int32).tobytes(), "color": item["color"],
                              "opacity": item["opacity"], "key": self.meshes[h].key()})
            else:
                items.append(dict(item))
        return {"n": self.n, "t": self.t, "user": self.user.ravel().tolist(), "head": self.head.tolist(),
                "flags": sorted(k for k, v in self.flags.items() if v), "quantum": self.quantum, "items": items}

    @classmethod
    def from_snapshot(cls, data: dict) -> "ClusterState":
        """Rebuild a state from :meth:`snapshot` data received from the network, checking every
        field (raises :class:`~softvr.cave.protocol.PacketError`)."""
        try:
            return cls._from_snapshot(data)
        except PacketError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError, IndexError) as exc:
            raise PacketError("malformed", f"snapshot: {type(exc).__name__}: {exc}") from None

    @classmethod
    def _from_snapshot(cls, data: dict) -> "ClusterState":
        quantum = float(data["quantum"])
        if not 1e-9 <= quantum <= 1.0:
            raise PacketError("malformed", "snapshot quantum: expected 1e-9..1 m")
        if not isinstance(data["items"], list) or len(data["items"]) > MAX_MESHES:
            raise PacketError("malformed", f"snapshot items: expected a list of at most {MAX_MESHES}")
        items, keys = [], {}
        for h, raw in enumerate(data["items"]):
            kind = raw["kind"]
            color = _check_floats(raw["color"], (3,), "color").tolist()
            if kind == "mesh":
                if len(raw["rest"]) > 24 * MAX_VERTICES:
                    raise PacketError("malformed", f"snapshot mesh {h}: more than {MAX_VERTICES} vertices")
                rest = np.frombuffer(raw["rest"], float).reshape(-1, 3).copy()
                faces = np.frombuffer(raw["faces"], np.int32).reshape(-1, 3).copy()
                if not np.isfinite(rest).all() or (faces.size and (faces.min() < 0 or faces.max() >= len(rest))):
                    raise PacketError("malformed", f"snapshot mesh {h}: non-finite vertices or bad face indices")
                items.append({"kind": "mesh", "rest": rest, "faces": faces, "color": color,
                              "opacity": _positive(raw["opacity"], "opacity", 1.0)})
                keys[h] = raw["key"]
            elif kind == "plane":
                normal = _check_floats(raw["normal"], (3,), "plane normal")
                if not np.linalg.norm(normal) > 1e-6:  # a renderer cannot orient a plane without one
                    raise PacketError("malformed", f"snapshot plane {h}: a zero normal")
                items.append({"kind": "plane", "point": _check_floats(raw["point"], (3,), "plane point").tolist(),
                              "normal": normal.tolist(), "size": _positive(raw["size"], "plane size"),
                              "color": color, "tiles": _integer(raw["tiles"], "plane tiles", 1, 256)})
            elif kind == "sphere":
                items.append({"kind": "sphere", "center": _check_floats(raw["center"], (3,), "center").tolist(),
                              "radius": _positive(raw["radius"], "radius"), "color": color,
                              "opacity": _positive(raw["opacity"], "opacity", 1.0)})
            else:
                raise PacketError("malformed", f"snapshot item {h}: unknown kind {kind!r}")
        state = cls(items, quantum)
        for h, key in keys.items():
            if key is not None:
                state.meshes[h].apply(check_mesh_update([h, *key])[1:])
        state.n = _integer(data["n"], "n", -1, MAX_FRAME)
        state.t = _check_floats([data["t"]], (1,), "t")[0].item()
        state.user = np.asarray(check_user(data["user"]), float).reshape(4, 4)
        state.head = np.asarray(check_head(data["head"]), float)
        flags = data["flags"]
        if not (isinstance(flags, list) and len(flags) <= _MAX_FLAGS
                and all(isinstance(f, str) and 0 < len(f) <= MAX_NAME for f in flags)):
            raise PacketError("malformed", f"snapshot flags: expected at most {_MAX_FLAGS} names")
        state.flags = dict.fromkeys(flags, True)
        return state


class FrameBuilder:
    """The master's side of an application: each frame's packet from a frame source, the
    navigation and the tracker, and the master's own :class:`ClusterState`.

    Parameters
    ----------
    source
        ``items`` (:func:`mesh_item`, :func:`plane_item`, :func:`sphere_item`), ``advance()`` -> mesh
        handle -> vertices [v, 3] [m] of the next frame, ``fps`` [1/s].
    navigation : callable, optional
        ``navigation(n, t)`` -> (user pose [4, 4] world <- tracker, head pose [7] or None,
        events [(name, args)]); None: the user stands still.
    tracker : optional
        ``poll()`` -> a pose with ``position`` [3] [m] and ``orientation`` (w, x, y, z);
        overrides the navigation's head.
    quantum : float [m]
        Vertex quantization of the mesh stream.
    """

    def __init__(self, source, *, navigation=None, tracker=None, quantum: float = DEFAULT_QUANTUM):
        self.source, self.navigation, self.tracker = source, navigation, tracker
        self.fps = float(getattr(source, "fps", 60.0))
        self.state = ClusterState(source.items, quantum)
        self.encoders = {h: MeshEncoder(i["rest"], quantum) for h, i in enumerate(source.items) if i["kind"] == "mesh"}

    def next_packet(self, session: int) -> bytes:
        """Advance the source one frame; returns the frame's packet, already applied to
        :attr:`state` through the nodes' own decoder (one code path, equal states)."""
        n = self.state.n + 1
        t = n / self.fps
        vertices = self.source.advance()
        meshes = [[h, *u] for h, e in self.encoders.items() if (u := e.encode(vertices[h])) is not None]
        user, head, events = self.navigation(n, t) if self.navigation else (self.state.user, None, [])
        if self.tracker is not None:
            pose = self.tracker.poll()
            head = np.r_[pose.position, pose.orientation]
        head = self.state.head if head is None else head
        payload = {"n": n, "t": t, "user": np.asarray(user, float).ravel().tolist(),
                   "head": np.asarray(head, float).tolist(), "events": [[e, list(a)] for e, a in events],
                   "meshes": meshes}
        packet = encode("frame", session, payload)
        self.state.apply_frame(decode(packet, session).payload)
        return packet


class PlayerSource:
    """Frames from a scene played by its :class:`softvr.app.Player`: every frame steps the player
    one frame and streams its :meth:`~softvr.app.Player.drawables` (plain arrays read from the
    player, no renderer in between).

    The items are the drawables in their order: planes (:func:`plane_item`, in
    :data:`~softvr.app.PLANE_TILES` tiles as every view draws them), static spheres
    (:func:`sphere_item`) and meshes (:func:`mesh_item`). A drawable on layer ``hidden`` (a
    volume's skin, drawn as the volume) is left out; what only a window draws (lights, the
    volume) is not streamed.
    """

    def __init__(self, player):
        self.player = player
        self.fps = float(player.fps)
        self.items: list[dict] = []
        self._meshes: dict[int, int] = {}  # mesh handle -> index in the player's drawables
        for k, d in enumerate(player.drawables()):
            if d.layer == "hidden":
                continue
            if d.kind == "plane":
                self.items.append(plane_item(d.point, d.normal, d.size, d.color, tiles=PLANE_TILES))
            elif d.kind == "sphere":
                self.items.append(sphere_item(d.point, d.size, d.color, d.opacity))
            else:
                self._meshes[len(self.items)] = k
                self.items.append(mesh_item(d.vertices, d.triangles, d.color, d.opacity))

    def vertices(self) -> dict:
        """Mesh handle -> the drawable's vertices [v, 3] [m] now."""
        drawables = self.player.drawables()
        return {h: drawables[k].vertices for h, k in self._meshes.items()}

    def advance(self) -> dict:
        """Step the player one frame (its sub-steps and hooks); mesh handle -> vertices [v, 3] [m]."""
        self.player.step()
        return self.vertices()

    def bounds(self) -> np.ndarray:
        return scene_bounds(self.items, self.vertices())

    def close(self) -> None:
        """Stop what the player started (haptic processes)."""
        self.player.close()


class SceneFileSource:
    """A static scene from a mesh file (glTF / GLB scenes keep one mesh per node, with its base
    colour; OBJ, STL, PLY load as one mesh) over a ground plane, for walking through on a
    display. glTF's y-up is turned to softvr's z-up."""

    fps = 60.0

    def __init__(self, path):
        import trimesh  # noqa: PLC0415 - heavy, and only a walk-through scene needs it

        path = Path(path)
        # A regular file of bounded size; trimesh's errors (every type) wrapped, naming the file.
        scene = native_read(lambda p: trimesh.load(p, force="scene"), path, "scene file",
                            "a readable glTF / GLB / OBJ / STL / PLY file")
        y_up = path.suffix.lower() in (".gltf", ".glb")
        meshes = []
        for node in scene.graph.nodes_geometry:
            transform, name = scene.graph[node]
            mesh = scene.geometry[name]
            if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
                continue  # points, paths
            v = trimesh.transformations.transform_points(np.asarray(mesh.vertices, float), transform)
            if y_up:
                v = np.c_[v[:, 0], -v[:, 2], v[:, 1]]
            color = np.asarray(getattr(mesh.visual, "main_color", (204, 204, 204, 255)), float)[:3] / 255.0
            meshes.append((v, np.asarray(mesh.faces, np.int32), color))
        if not meshes:
            raise InputError("scene file", "at least one triangle mesh", "none", source=str(path))
        low = min(v[:, 2].min() for v, _, _ in meshes)
        span = max(np.ptp(np.vstack([v for v, _, _ in meshes]), axis=0).max(), 1e-3)
        self.items = [plane_item(point=(0.0, 0.0, low), size=3.0 * span, tiles=12)]
        self.items += [mesh_item(v, f, color=color) for v, f, color in meshes]
        self.vertices = {h: i["rest"] for h, i in enumerate(self.items) if i["kind"] == "mesh"}

    def advance(self) -> dict:
        return self.vertices

    def bounds(self) -> np.ndarray:
        return scene_bounds(self.items, self.vertices)


class WavingSheet:
    """An analytic deforming body: a square sheet of ``side`` [m] with ``vertices`` grid points
    rippled by travelling waves (amplitude ``amplitude`` [m]), over a ground plane; a box
    turning above it moves rigidly (streamed as a pose)."""

    def __init__(self, vertices: int = 10_000, side: float = 1.0, amplitude: float = 0.05, fps: float = 60.0):
        k = max(int(round(math.sqrt(vertices))), 2)
        x, y = np.meshgrid(np.linspace(-side / 2, side / 2, k), np.linspace(-side / 2, side / 2, k), indexing="ij")
        self.grid = np.c_[x.ravel(), y.ravel()]
        quads = np.arange(k * k).reshape(k, k)[:-1, :-1].ravel()
        faces = np.concatenate([np.c_[quads, quads + k, quads + k + 1], np.c_[quads, quads + k + 1, quads + 1]])
        self.amplitude, self.fps, self.frame = float(amplitude), float(fps), 0
        self._box = box_corners((0.08, 0.08, 0.08))
        self.sheet, self.box = 1, 2  # the handles of the sheet and the box
        self.items = [plane_item(point=(0.0, 0.0, 0.0), size=3.0, tiles=12),
                      mesh_item(self._sheet(0.0), faces, color=(0.85, 0.45, 0.35)),
                      mesh_item(self._box_at(0.0), BOX_TRIANGLES, color=(0.3, 0.55, 0.85))]
        self.vertices = {self.sheet: self.items[1]["rest"], self.box: self.items[2]["rest"]}

    def _sheet(self, t: float) -> np.ndarray:
        x, y = self.grid[:, 0], self.grid[:, 1]
        z = 0.4 + self.amplitude * (np.sin(8 * x - 3 * t) + 0.5 * np.sin(6 * y + 2 * t))
        return np.c_[x, y, z]

    def _box_at(self, t: float) -> np.ndarray:
        c, s = math.cos(t), math.sin(t)
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return self._box @ rotation.T + (0.0, 0.0, 0.8)

    def advance(self) -> dict:
        self.frame += 1
        t = self.frame / self.fps
        self.vertices = {self.sheet: self._sheet(t), self.box: self._box_at(t)}
        return self.vertices

    def bounds(self) -> np.ndarray:
        return scene_bounds(self.items, self.vertices)
