"""Streaming body states from the master to the render nodes, compactly and exactly.

The thesis' cluster could not show a deformation simulated on the master (every node would
have to simulate it). Here the master sends, per surface mesh and frame, the cheapest of:

* ``pose`` — a rigid motion of the mesh's first vertex set (7 numbers: position [m] and unit
  quaternion w x y z), when the fitted rigid transform reproduces every vertex within half
  a quantum;
* ``delta`` — vertex positions quantized to integers of ``quantum`` metres (default 10 um),
  minus the previous frame's integers, packed as int8 / int16 / int32 (the narrowest that
  holds the largest change) and zlib-compressed;
* ``key`` — the absolute integers (int32, zlib), after a pose, on a snapshot, or when a delta
  would be larger;
* nothing, when the mesh did not move.

Quantized integers add exactly, so a node that applied every delta holds bit for bit the
master's integers (no drift); a node that missed one has a sequence gap and resyncs from a
snapshot. Positions are off by at most ``quantum / 2`` from the simulation.
"""

from __future__ import annotations

import zlib

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["DEFAULT_QUANTUM", "MeshDecoder", "MeshEncoder", "fit_rigid", "pose_matrix"]

DEFAULT_QUANTUM = 1e-5
_WIDTH_DTYPE = {1: np.int8, 2: np.int16, 4: np.int32}


def pose_matrix(pose) -> tuple[np.ndarray, np.ndarray]:
    """Rotation [3, 3] and translation [3] of a pose [7] (position [m], quaternion w x y z)."""
    p = np.asarray(pose, float)
    w, x, y, z = p[3:]
    return Rotation.from_quat((x, y, z, w)).as_matrix(), p[:3]  # SciPy normalises the quaternion


def fit_rigid(rest: np.ndarray, current: np.ndarray) -> tuple[np.ndarray, float]:
    """The rigid motion taking ``rest`` [v, 3] [m] closest to ``current`` [v, 3] (Kabsch) as a
    pose [7], and the largest vertex distance [m] it leaves."""
    c0, c1 = rest.mean(axis=0), current.mean(axis=0)
    u, _, vt = np.linalg.svd((rest - c0).T @ (current - c1))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    q = np.array([w, x, y, z])
    r, _ = pose_matrix(np.r_[0.0, 0.0, 0.0, q])  # the rotation the node will rebuild from q
    t = c1 - c0 @ r.T
    error = float(np.abs(rest @ r.T + t - current).max()) if len(rest) else 0.0
    return np.r_[t, q], error


def _pack(values: np.ndarray, width: int) -> bytes:
    return zlib.compress(values.astype(_WIDTH_DTYPE[width]).tobytes(), 1)


def _unpack(data: bytes, width: int, count: int) -> np.ndarray:
    size = count * 3 * width
    d = zlib.decompressobj()
    try:
        # Bounded by what the mesh holds: a zip bomb stops one byte past it (max_length 0
        # would mean "unlimited", so an empty mesh gets 1).
        raw = d.decompress(data, size + 1)
    except zlib.error as exc:
        raise ValueError(f"corrupt mesh data ({exc})") from None
    if len(raw) != size or d.unconsumed_tail or not d.eof:
        raise ValueError(f"expected {size} bytes of int{8 * width} for {count} vertices")
    return np.frombuffer(raw, _WIDTH_DTYPE[width]).reshape(count, 3)


class MeshEncoder:
    """The master's side for one mesh: first vertices ``rest`` [v, 3] [m] (the pose's frame)."""

    def __init__(self, rest, quantum: float = DEFAULT_QUANTUM, *, rigid: bool = True):
        self.rest = np.array(rest, float)
        self.quantum = float(quantum)
        self.rigid = rigid
        self._ints: np.ndarray | None = None  # the integers the nodes hold after the last key / delta
        self._pose: np.ndarray | None = None

    def encode(self, vertices) -> list | None:
        """The update [kind, data...] that brings a node to ``vertices`` [v, 3] [m] (module
        docstring), or ``None`` when nothing changed."""
        v = np.asarray(vertices, float)
        if self.rigid and len(v) >= 3:
            pose, error = fit_rigid(self.rest, v)
            if error <= 0.5 * self.quantum:
                if self._pose is not None and np.array_equal(pose, self._pose):
                    return None
                self._pose, self._ints = pose, None
                return ["pose", pose.tolist()]
        ints = np.rint(v / self.quantum).astype(np.int64)
        if np.abs(ints).max(initial=0) >= 2**31:
            raise ValueError(f"a vertex beyond +-{2**31 * self.quantum:.3g} m cannot be streamed at this quantum")
        self._pose = None
        if self._ints is None:
            self._ints = ints
            return ["key", _pack(ints, 4)]
        delta = ints - self._ints
        self._ints = ints
        largest = int(np.abs(delta).max(initial=0))
        if largest == 0:
            return None
        width = 1 if largest < 128 else 2 if largest < 32768 else 4
        return ["delta", width, _pack(delta, width)]


class MeshDecoder:
    """A node's copy of one mesh: ``rest`` [v, 3] [m], and either a ``pose`` [7] or the
    quantized integers ``ints`` [v, 3] (int32, units of ``quantum``); :meth:`vertices`
    [v, 3] [m] what to draw."""

    def __init__(self, rest, quantum: float = DEFAULT_QUANTUM):
        self.rest = np.array(rest, float)
        self.quantum = float(quantum)
        self.pose: np.ndarray | None = None
        self.ints: np.ndarray | None = None

    def apply(self, update) -> None:
        """Apply a validated update (:func:`softvr.cave.protocol.decode`'s ``meshes`` entry
        without its handle). Raises ``ValueError`` if it does not fit this mesh (then the
        node resyncs)."""
        kind = update[0]
        n = len(self.rest)
        if kind == "pose":
            self.pose, self.ints = np.asarray(update[1], float), None
            if not np.linalg.norm(self.pose[3:]) > 0:
                raise ValueError("a pose with a zero quaternion")
        elif kind == "key":
            self.ints, self.pose = _unpack(update[1], 4, n).copy(), None
        elif kind == "delta":
            if self.ints is None:
                raise ValueError("a delta with no key before it")
            # int32 holds every position the encoder allows (|integer| < 2**31): exact sums.
            np.add(self.ints, _unpack(update[2], update[1], n), out=self.ints, casting="unsafe")
        else:
            raise ValueError(f"unknown mesh update {kind!r}")

    def vertices(self) -> np.ndarray:
        if self.pose is not None:
            r, t = pose_matrix(self.pose)
            return self.rest @ r.T + t
        if self.ints is not None:
            return self.ints * self.quantum
        return self.rest

    def key(self) -> list | None:
        """The current state as a self-contained update (for snapshots)."""
        if self.pose is not None:
            return ["pose", self.pose.tolist()]
        if self.ints is not None:
            return ["key", _pack(self.ints, 4)]
        return None

    def state_bytes(self) -> bytes:
        """What the state hash covers: the pose's or the integers' exact bytes."""
        if self.pose is not None:
            return b"P" + self.pose.tobytes()
        if self.ints is not None:
            return b"Q" + self.ints.tobytes()
        return b"R"
