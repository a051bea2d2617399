"""The start checks of a built scene: which surfaces must start apart, which cross, which lie
below a plane, and the collision-free start that pushes soft bodies out of each other
(thesis 5.2.3). Plain data in, plain data out: named surfaces (objects with ``vertices()``
[n, 3] [m] and ``triangles`` [t, 3]), the bodies by name, the planes.

``softvr check`` runs these on a scene that is built but not started (no haptic process, no
renderer): :meth:`softvr.scene.SceneExample.start_problems`.
"""

from __future__ import annotations

import numpy as np

from softvr.dynamics import embed_in_tets
from softvr.model import intersecting_triangle_pairs, push_apart

__all__ = ["collision_free_start", "crossing", "start_pairs", "start_problems"]


def start_pairs(names: list, obstacles: list, may_collide, apart: set) -> list:
    """Name pairs whose surfaces must start apart.

    Parameters
    ----------
    names : list of str
        Bodies with a surface (cloth, an open sheet, left out by the caller).
    obstacles : list of str
        Fixed meshes (static obstacles, not bodies): every body is paired with every one.
    may_collide : callable
        ``may_collide(a, b)``: whether the scene lets bodies ``a`` and ``b`` collide.
    apart : set of frozenset
        Pairs coupled without contact.
    """
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]
             if may_collide(a, b) and frozenset((a, b)) not in apart]
    return pairs + [(a, o) for a in names for o in obstacles]


def crossing(a, b) -> np.ndarray:
    """Crossing triangle pairs [k, 2] of two surfaces."""
    return intersecting_triangle_pairs(a.vertices(), a.triangles, b.vertices(), b.triangles)


def collision_free_start(bodies: dict, surfaces: dict, pairs: list, rounds: int = 4) -> list:
    """Push every soft body that starts crossing another out of it (:func:`softvr.model.push_apart`:
    a smooth deformation of its tets; it starts from that deformed state, its rest shape
    unchanged).

    Of two soft bodies the one with fewer tets moves; two rigid ones are left
    (:func:`start_problems` reports them). Pushing one body out can push it into a third, so
    the pairs are swept until nothing moves (at most ``rounds`` sweeps).

    Parameters
    ----------
    bodies : dict
        Name -> contact object; a soft one has ``tets``, ``q`` [n, 3] [m] (moved in place) and ``fixed`` [n].
    surfaces : dict
        Name -> surface of every name in ``pairs`` (bodies and fixed meshes).
    pairs : list of (str, str)
        From :func:`start_pairs`.

    Returns
    -------
    list of (str, str, float)
        (moved body, obstacle, its largest node displacement [m]).
    """
    def soft(name) -> bool:
        body = bodies.get(name)
        return body is not None and hasattr(body, "tets") and not body.fixed.all()

    start: dict[str, np.ndarray] = {}  # moved body -> its nodes before
    pushed = []
    for _ in range(rounds):
        changed = False
        for a, b in pairs:
            if not (soft(a) or soft(b)) or not len(crossing(surfaces[a], surfaces[b])):
                continue
            smaller = soft(a) and (not soft(b) or len(bodies[a].tets) <= len(bodies[b].tets))
            mover, obstacle = (a, b) if smaller else (b, a)
            body, surface, other = bodies[mover], surfaces[mover], surfaces[obstacle]
            start.setdefault(mover, body.q.copy())
            embedding = embed_in_tets(body.q, body.tets, surface.vertices(), tolerance=np.inf)
            nodes, report = push_apart(body.q, body.tets, embedding, surface.triangles, other.vertices(),
                                       other.triangles)
            nodes[body.fixed] = body.q[body.fixed]  # clamped nodes stay where the scene put them
            body.q[:] = nodes
            if report.max_displacement > 0:  # none of its vertices inside: nothing to push
                changed = True
                if (mover, obstacle) not in pushed:
                    pushed.append((mover, obstacle))
        if not changed:
            break
    return [(a, b, float(np.linalg.norm(bodies[a].q - start[a], axis=1).max())) for a, b in pushed]


def start_problems(body_surfaces: dict, surfaces: dict, planes: list, pairs: list) -> list:
    """(what, expected, found) for bodies that start below a plane or crossing each other or a
    fixed mesh (crossing surface triangles).

    Parameters
    ----------
    body_surfaces : dict
        Name -> surface of every body (checked against the planes).
    surfaces : dict
        Name -> surface of every name in ``pairs``.
    planes : list of Plane
        With ``point`` [3] [m] and ``unit_normal()``.
    pairs : list of (str, str)
        From :func:`start_pairs`.
    """
    out = []
    for a, surface in body_surfaces.items():
        for plane in planes:
            depth = float(-((surface.vertices() - np.asarray(plane.point)) @ plane.unit_normal()).min())
            if depth > 1e-6:
                out.append((f"body {a!r}", "a start above every plane", f"{depth * 1e3:.2f} mm below one"))
    for a, b in pairs:
        found = crossing(surfaces[a], surfaces[b])
        if len(found):
            out.append((f"bodies {a!r} and {b!r}", "surfaces apart at the start",
                        f"{len(found)} crossing triangle pairs"))
    return out
