"""Simple closed surfaces shared by the scene builder, the demos and the benchmarks."""

from __future__ import annotations

import numpy as np

__all__ = ["BOX_TRIANGLES", "box_corners", "box_surface", "icosphere"]

#: Corner k = 4 i + 2 j + l of :func:`box_corners` has signs (i, j, l) (0: -, 1: +); two
#: outward (counter-clockwise from outside) triangles per face.
BOX_TRIANGLES = np.array([
    [0, 1, 3], [0, 3, 2],  # -x
    [4, 6, 7], [4, 7, 5],  # +x
    [0, 4, 5], [0, 5, 1],  # -y
    [2, 3, 7], [2, 7, 6],  # +y
    [0, 2, 6], [0, 6, 4],  # -z
    [1, 5, 7], [1, 7, 3],  # +z
], np.int32)

_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)


def box_corners(half_extents) -> np.ndarray:
    """The 8 corners [8, 3] [m] of a box centred on the origin with ``half_extents`` [3] [m],
    in the vertex order of :data:`BOX_TRIANGLES`."""
    return _SIGNS * np.asarray(half_extents, float)


def box_surface(size, quads: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed, outward triangulated surface of the box [0, size] with about ``quads`` quads along
    its longest edge (square-ish quads on every face). Returns vertices [n, 3] [m] and
    triangles [t, 3]."""
    size = np.asarray(size, float)
    counts = np.maximum(1, np.round(size / size.max() * quads).astype(int))
    verts: list[np.ndarray] = []
    tris: list[tuple[int, int, int]] = []
    index: dict[tuple, int] = {}

    def vertex(p):
        key = tuple(np.round(p / size * 2 * counts.max()).astype(int))
        if key not in index:
            index[key] = len(verts)
            verts.append(p)
        return index[key]

    for axis in range(3):
        u, w = (axis + 1) % 3, (axis + 2) % 3
        for side in (0.0, 1.0):
            for i in range(counts[u]):
                for j in range(counts[w]):
                    corners = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = np.zeros(3)
                        p[axis] = side * size[axis]
                        p[u] = (i + di) / counts[u] * size[u]
                        p[w] = (j + dj) / counts[w] * size[w]
                        corners.append(vertex(p))
                    a, b, c, d = corners
                    # (u, w, axis) is right-handed: counter-clockwise seen from +axis on side 1.
                    tris += [(a, b, c), (a, c, d)] if side else [(a, c, b), (a, d, c)]
    return np.array(verts), np.array(tris, np.int32)


def icosphere(subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere of subdivided icosahedron triangles, counter-clockwise from outside.

    Returns vertices [10 * 4^s + 2, 3] on the unit sphere and triangles [20 * 4^s, 3].
    """
    t = (1 + 5**0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
         (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
         (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.asarray(p, float) / np.linalg.norm(p) for p in v]
    faces = [tuple(x) for x in f]
    for _ in range(subdivisions):
        cache: dict = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                p = verts[a] + verts[b]
                verts.append(p / np.linalg.norm(p))
                cache[key] = len(verts) - 1
            return cache[key]

        new: list[tuple[int, ...]] = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(verts), np.array(faces, np.int32)
