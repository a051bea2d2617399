"""``softvr build-model PARTS.toml``: from part meshes to a ready simulation model (thesis 5.2).

For every part of the parts file (:mod:`softvr.model.parts`): its mesh is the render surface;
the collision surface is its quadric simplification; a soft part gets a tet mesh of the cubes
touching it with both surfaces embedded; a rigid one gets its mass properties from the closed
surface (``trimesh``). Couplings bind the chosen nodes of part ``a`` (tet nodes of a soft part,
collision vertices of a rigid one) to part ``b`` where they are. Then the collision-free start
(:func:`softvr.model.push_apart`): every soft part that crosses a part it may collide with is
deformed out of it; crossings that remain are reported.

The result, a :class:`Model`, is saved as one ``.npz`` file (a JSON manifest inside, versioned)
and turned into a :class:`softvr.Scene` by :meth:`Model.build_scene`.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from softvr.dynamics import (Coupling, EmbeddedPoints, FemBody, FixedBody, KinematicBody, Material, RigidBody,
                             RigidPoints, embed_in_tets)
from softvr.errors import InputError
from softvr.files import atomic_output, check_npz, load_json, native_read
from softvr.geometry import tet_signed_volumes
from softvr.gltf import check_gltf
from softvr.model.couplings import nodes_near_surface
from softvr.model.intersections import intersecting_triangle_pairs
from softvr.model.parts import CouplingSpec, PartSpec, PartsFile, read_parts
from softvr.model.representations import collision_mesh, dynamics_mesh, embed_surface
from softvr.model.separation import push_apart
from softvr.sim import Scene

__all__ = ["Model", "PartModel", "build_model", "load_mesh", "load_model", "main"]

MODEL_FORMAT = "softvr-model 1"


def load_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [n, 3] [m] and triangles [t, 3] of a mesh file (OBJ, STL, PLY, glTF / GLB, OFF;
    a glTF scene's meshes are merged in world coordinates)."""
    import trimesh  # noqa: PLC0415

    path = Path(path)
    if path.suffix.lower() in (".gltf", ".glb"):
        # Its buffers and images are files too: checked (inside its folder, regular) before trimesh.
        check_gltf(path)
    mesh = native_read(lambda file: trimesh.load(file, force="mesh", process=True), path, "mesh",
                       "a readable triangle mesh")
    v, t = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    if len(t) < 4:
        raise InputError("mesh", "a closed surface of at least 4 triangles", f"{len(t)} triangles", source=str(path))
    if not np.all(np.isfinite(v)) or t.min() < 0 or t.max() >= len(v):
        raise InputError("mesh", "finite vertices and triangles that index them",
                         f"{len(v)} vertices, triangle indices {t.min()} .. {t.max()}", source=str(path))
    return v, t.astype(np.int32)


@dataclass
class PartModel:
    """One part's representations (arrays in metres; soft parts only have tets).

    Attributes
    ----------
    spec : PartSpec
    render_vertices, render_triangles : [n, 3] [m], [t, 3]
    collision_vertices, collision_triangles : [k, 3] [m], [c, 3]
    rest_nodes, start_nodes : [node_count, 3] [m]
        Soft parts: the tet nodes at rest, and where the simulation starts (the collision-free
        deformation of them).
    tets : [tet_count, 4]
    render_embedding, collision_embedding : (tet_index [n], weights [n, 4])
    mass : float [kg]
    center : [3] [m]
        Rigid parts: centre of mass (the body frame's origin; axes those of the world).
    inertia : [3, 3] [kg m^2]
        Rigid parts: inertia about the centre of mass.
    """

    spec: PartSpec
    render_vertices: np.ndarray
    render_triangles: np.ndarray
    collision_vertices: np.ndarray
    collision_triangles: np.ndarray
    rest_nodes: np.ndarray | None = None
    start_nodes: np.ndarray | None = None
    tets: np.ndarray | None = None
    render_embedding: tuple | None = None
    collision_embedding: tuple | None = None
    mass: float = 0.0
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inertia: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def soft(self) -> bool:
        return self.spec.kind == "soft"

    def collision_now(self) -> np.ndarray:
        """Collision vertices at the start state [k, 3] [m]."""
        if not self.soft:
            return self.collision_vertices
        assert self.collision_embedding is not None and self.start_nodes is not None and self.tets is not None
        index, weights = self.collision_embedding
        return np.einsum("pk,pkc->pc", weights, self.start_nodes[self.tets[index]])


@dataclass
class Model:
    """Parts, couplings (with their node lists) and the start-state report.

    Attributes
    ----------
    parts : list of PartModel
    couplings : list of (CouplingSpec, ndarray [k, 3] [m])
        Each coupling with the world positions of its springs at rest.
    crossings : dict[str, int]
        ``"a / b"`` -> triangle pairs still crossing after the collision-free start.
    """

    parts: list
    couplings: list
    crossings: dict

    def part(self, name: str) -> PartModel:
        for p in self.parts:
            if p.spec.name == name:
                return p
        raise InputError("part", f"one of {[p.spec.name for p in self.parts]}", repr(name))

    # -- to a scene ------------------------------------------------------------------------
    def build_scene(self, scene=None):
        """Add every part and coupling to ``scene`` (a new :class:`softvr.Scene` by default).

        Returns ``(scene, bodies, render_points)``: bodies by part name, and per part the
        point entity whose ``positions()`` are its render vertices.
        """
        scene = Scene() if scene is None else scene
        bodies, render = {}, {}
        for part in self.parts:
            s = part.spec
            if part.soft:
                body = FemBody(part.rest_nodes, part.tets, Material(s.young, s.poisson, s.density, alpha=s.alpha,
                                                                     beta=s.beta), name=s.name)
                body.q[:] = part.start_nodes
                ti, w = part.collision_embedding
                points = EmbeddedPoints(body, part.tets[ti], w)
                ri, rw = part.render_embedding
                render[s.name] = EmbeddedPoints(body, part.tets[ri], rw)
            else:
                if s.kind == "rigid":
                    body = RigidBody(part.mass, part.inertia, position=part.center, name=s.name)
                elif s.kind == "fixed":
                    body = FixedBody(position=part.center, name=s.name)
                else:  # kinematic: holds its pose until the application scripts it
                    center = part.center.copy()
                    body = KinematicBody(lambda t, c=center: (c, np.array([1.0, 0.0, 0.0, 0.0])), name=s.name)
                points = RigidPoints(body, part.collision_vertices - part.center)
                render[s.name] = RigidPoints(body, part.render_vertices - part.center)
            scene.add_body(body, collision_points=points, collision_triangles=part.collision_triangles)
            bodies[s.name] = body
        for spec, springs in self.couplings:
            a, b = self.part(spec.a), self.part(spec.b)
            sides = []
            for part, body in ((a, bodies[spec.a]), (b, bodies[spec.b])):
                if part.soft:
                    # Springs at nodes near (not inside) b bind to b's nearest tet, extrapolated.
                    ti, w = embed_in_tets(part.start_nodes, part.tets, springs, tolerance=np.inf)
                    sides.append(EmbeddedPoints(body, part.tets[ti], w))
                else:
                    sides.append(RigidPoints.from_world(body, springs))
            scene.add_coupling(Coupling(sides[0], sides[1], spec.stiffness, damping=spec.damping,
                                        name=f"{spec.a} - {spec.b}"), collide=spec.collide)
        return scene, bodies, render

    # -- files -----------------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write the model to ``path`` (``.npz``) atomically; returns the path."""
        arrays: dict[str, Any] = {}  # name -> array (np.savez's keywords)
        manifest: dict[str, Any] = {"format": MODEL_FORMAT, "parts": [], "couplings": [], "crossings": self.crossings}
        for i, p in enumerate(self.parts):
            entry = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(p.spec).items()}
            manifest["parts"].append({"spec": entry, "mass": p.mass})
            for key in ("render_vertices", "render_triangles", "collision_vertices", "collision_triangles",
                        "rest_nodes", "start_nodes", "tets", "center", "inertia"):
                value = getattr(p, key)
                if value is not None:
                    arrays[f"p{i}_{key}"] = np.asarray(value)
            for key in ("render_embedding", "collision_embedding"):
                if getattr(p, key) is not None:
                    arrays[f"p{i}_{key}_tet"], arrays[f"p{i}_{key}_weights"] = getattr(p, key)
        for i, (spec, springs) in enumerate(self.couplings):
            manifest["couplings"].append(vars(spec))
            arrays[f"c{i}_springs"] = springs
        arrays["manifest"] = np.array(json.dumps(manifest))
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path, ".npz") as tmp:
            with open(tmp, "wb") as f:
                np.savez_compressed(f, **arrays)
        return path


def load_model(path) -> Model:
    """Read a model saved by :meth:`Model.save`; a file that is not one (a bad manifest,
    arrays of the wrong shapes or indices out of range) is an :class:`InputError` naming the
    file and the entry."""
    path = check_npz(path, "model")
    source = str(path)
    try:
        data = np.load(path, allow_pickle=False)
        manifest = load_json(str(data["manifest"]), "model manifest", source)
    except (OSError, KeyError, ValueError) as exc:
        raise InputError("model", f"a {MODEL_FORMAT} .npz file", f"{type(exc).__name__}: {exc}", source=source) from None
    if not isinstance(manifest, dict) or manifest.get("format") != MODEL_FORMAT:
        raise InputError("format", MODEL_FORMAT, repr(manifest.get("format") if isinstance(manifest, dict)
                                                      else manifest)[:100], source=source)
    entries, links, crossings = manifest.get("parts"), manifest.get("couplings"), manifest.get("crossings", {})
    if not (isinstance(entries, list) and entries and all(
            isinstance(e, dict) and isinstance(e.get("spec"), dict) for e in entries)):
        raise InputError("manifest.parts", "a list of {spec, mass} entries", repr(entries)[:100], source=source)
    if not (isinstance(links, list) and all(isinstance(c, dict) for c in links) and isinstance(crossings, dict)):
        raise InputError("manifest.couplings", "a list of couplings and a crossings table", repr(links)[:100],
                         source=source)
    parts = [_loaded_part(data, i, entry, source) for i, entry in enumerate(entries)]
    names = {p.spec.name for p in parts}
    couplings = []
    for i, c in enumerate(links):
        fields = set(CouplingSpec.__dataclass_fields__)
        ends = c.get("a"), c.get("b")
        if not (set(c) <= fields and all(isinstance(e, str) and e in names for e in ends)
                and _finite(c.get("stiffness")) and _finite(c.get("damping", 0.0))
                and (c.get("radius") is None or _finite(c["radius"])) and isinstance(c.get("collide", False), bool)
                and isinstance(c.get("nodes", []), list) and all(type(n) is int for n in c.get("nodes", []))):
            raise InputError(f"manifest.couplings[{i}]", f"a coupling of two parts ({', '.join(sorted(names))})",
                             repr(c)[:200], source=source)
        couplings.append((CouplingSpec(**c), _array(data, f"c{i}_springs", (None, 3), source)))
    return Model(parts=parts, couplings=couplings, crossings=crossings)


def _finite(x) -> bool:
    return type(x) in (int, float) and bool(np.isfinite(x))


def _array(data, key: str, shape: tuple, source: str, *, below: int | None = None) -> np.ndarray:
    """``data[key]`` if it has ``shape`` (None: any length) and finite numbers (integers in
    ``0 .. below - 1`` with ``below``); else an :class:`InputError` naming the entry."""
    if key not in data:
        raise InputError(key, f"an array of shape {shape}", "none", source=source)
    a = data[key]
    ok = a.ndim == len(shape) and all(n is None or a.shape[k] == n for k, n in enumerate(shape))
    if ok and below is not None:
        ok = np.issubdtype(a.dtype, np.integer) and (a.size == 0 or (a.min() >= 0 and a.max() < below))
    elif ok:
        ok = np.issubdtype(a.dtype, np.number) and bool(np.all(np.isfinite(a)))
    if not ok:
        expected = f"shape {shape}" + (f", indices in 0 .. {below - 1}" if below is not None else ", finite numbers")
        raise InputError(key, expected, f"shape {a.shape} of {a.dtype}", source=source)
    return a


def _loaded_part(data, i: int, entry: dict, source: str) -> PartModel:
    """Part ``i`` of a model file, every array checked against the others it indexes."""
    spec_fields = set(PartSpec.__dataclass_fields__)
    raw = entry["spec"]
    if not (set(raw) <= spec_fields and all(isinstance(raw.get(k), str) for k in ("name", "mesh", "kind"))
            and raw["kind"] in ("fixed", "kinematic", "rigid", "soft")):
        raise InputError(f"manifest.parts[{i}].spec", "a part (name, mesh, kind, ...)", repr(raw)[:200], source=source)
    numbers = ("density", "young", "poisson", "alpha", "beta", "cell_size", "friction")
    if not all(_finite(raw[k]) for k in numbers if k in raw) or type(raw.get("collision_triangles", 4)) is not int:
        raise InputError(f"manifest.parts[{i}].spec", "finite material numbers and an integer triangle budget",
                         repr(raw)[:200], source=source)
    spec = PartSpec(**{**raw, "mesh": Path(raw["mesh"])})
    mass: Any = entry.get("mass")  # checked next
    if not (type(mass) in (int, float) and np.isfinite(mass) and mass >= 0):
        raise InputError(f"manifest.parts[{i}].mass", "a mass >= 0 [kg]", repr(mass), source=source)
    kw: dict[str, Any] = {}
    for surface in ("render", "collision"):
        v = kw[f"{surface}_vertices"] = _array(data, f"p{i}_{surface}_vertices", (None, 3), source)
        kw[f"{surface}_triangles"] = _array(data, f"p{i}_{surface}_triangles", (None, 3), source, below=len(v))
    if spec.kind == "soft":
        nodes = kw["rest_nodes"] = _array(data, f"p{i}_rest_nodes", (None, 3), source)
        kw["start_nodes"] = _array(data, f"p{i}_start_nodes", (len(nodes), 3), source)
        tets = kw["tets"] = _array(data, f"p{i}_tets", (None, 4), source, below=len(nodes))
        for surface in ("render", "collision"):
            count = len(kw[f"{surface}_vertices"])
            kw[f"{surface}_embedding"] = (_array(data, f"p{i}_{surface}_embedding_tet", (count,), source,
                                                 below=len(tets)),
                                          _array(data, f"p{i}_{surface}_embedding_weights", (count, 4), source))
    elif spec.kind in ("rigid", "kinematic") or f"p{i}_center" in data:
        kw["center"] = _array(data, f"p{i}_center", (3,), source)
        kw["inertia"] = _array(data, f"p{i}_inertia", (3, 3), source)
    return PartModel(spec=spec, mass=float(mass), **kw)


def rigid_properties(v, t, density: float, name: str):
    """Mass [kg], centre of mass [3] [m] and inertia about it [3, 3] [kg m^2] of the solid a
    closed, outward triangle surface (``v`` [n, 3] [m], ``t`` [k, 3]) bounds, of uniform
    ``density`` [kg/m^3]; anything else is an :class:`InputError` naming ``name``."""
    import trimesh  # noqa: PLC0415

    mesh = trimesh.Trimesh(v, t, process=False)
    mesh.merge_vertices()  # glTF and OBJ exports split vertices along seams; geometry is what counts
    if not mesh.is_watertight or mesh.volume <= 0:
        raise InputError(f"{name} mesh", "a closed, outward surface (positive volume) for a rigid body",
                         f"watertight={mesh.is_watertight}, volume={mesh.volume:.3g} m^3")
    mesh.density = density
    return float(mesh.mass), np.asarray(mesh.center_mass, float), np.asarray(mesh.moment_inertia, float)


def _part_model(p: PartSpec) -> PartModel:
    """One part's render, collision and (soft) dynamics meshes or (rigid) mass properties."""
    v, t = load_mesh(p.mesh)
    cv, ct = collision_mesh(v, t, p.collision_triangles)
    part = PartModel(spec=p, render_vertices=v, render_triangles=t, collision_vertices=cv, collision_triangles=ct)
    if p.kind == "soft":
        nodes, tets = dynamics_mesh(np.vstack([v, cv]), np.vstack([t, ct + len(v)]), p.cell_size)
        part.rest_nodes, part.start_nodes, part.tets = nodes, nodes.copy(), tets
        part.render_embedding = embed_surface(nodes, tets, v)
        part.collision_embedding = embed_surface(nodes, tets, cv)
        part.mass = float(p.density * np.abs(tet_signed_volumes(nodes, tets)).sum())
    else:
        part.mass, part.center, part.inertia = rigid_properties(v, t, p.density, f"part {p.name!r}")
    return part


def build_model(parts, *, progress: bool = True, separation_iterations: int = 30, separation_rounds: int = 5) -> Model:
    """Build a :class:`Model` from a parts file (path or :class:`PartsFile`); the collision-free
    start sweeps the intersecting pairs up to ``separation_rounds`` times, each push taking up
    to ``separation_iterations`` relaxation steps."""
    spec = parts if isinstance(parts, PartsFile) else read_parts(parts)
    models = []
    for i, p in enumerate(tqdm(spec.parts, desc="parts", unit="part", disable=not progress)):
        try:
            models.append(_part_model(p))
        except InputError as exc:
            if exc.source is not None:  # a mesh file's own error names it
                raise
            raise InputError(f"part[{i}] ({p.name}).{exc.what}", exc.expected, exc.found, source=str(spec.path)) from None
    by_name = {m.spec.name: m for m in models}
    couplings = []
    for c in spec.couplings:
        a, b = by_name[c.a], by_name[c.b]
        candidates = a.start_nodes if a.soft else a.collision_vertices
        assert candidates is not None  # a soft part has its nodes
        chosen = set(int(n) for n in c.nodes)
        if any(n >= len(candidates) for n in chosen):
            raise InputError(f"coupling {c.a} - {c.b}.nodes", f"indices below {len(candidates)}", str(max(chosen)),
                             source=str(spec.path))
        if c.radius is not None:
            chosen |= set(nodes_near_surface(candidates, b.collision_vertices, b.collision_triangles, c.radius).tolist())
        if not chosen:
            raise InputError(f"coupling {c.a} - {c.b}", f"nodes of {c.a} within {c.radius} m of {c.b}", "none",
                             source=str(spec.path))
        couplings.append((c, candidates[sorted(chosen)].copy()))
    apart = {frozenset((c.a, c.b)) for c in spec.couplings if not c.collide}
    names = [m.spec.name for m in models]
    pairs = [(by_name[a], by_name[b]) for i, a in enumerate(names) for b in names[i + 1:]
             if frozenset((a, b)) not in apart]

    def crossing(a, b) -> int:
        return len(intersecting_triangle_pairs(a.collision_now(), a.collision_triangles, b.collision_now(),
                                               b.collision_triangles))

    # Pushing one part out of another can push it into a third: sweep the pairs until a sweep
    # moves nothing (or the budget is spent). The smaller soft part of a pair moves.
    for _ in range(separation_rounds):
        moved = False
        for a, b in pairs:
            if not (a.soft or b.soft) or not crossing(a, b):
                continue
            smaller = a.soft and (not b.soft or len(a.tets) <= len(b.tets))  # type: ignore[arg-type]  # soft: tets
            moving, obstacle = (a, b) if smaller else (b, a)
            moving.start_nodes, _ = push_apart(moving.start_nodes, moving.tets, moving.collision_embedding,
                                               moving.collision_triangles, obstacle.collision_now(),
                                               obstacle.collision_triangles, iterations=separation_iterations)
            moved = True
        if not moved:
            break
    crossings = {f"{a.spec.name} / {b.spec.name}": n for a, b in pairs if (n := crossing(a, b))}
    return Model(parts=models, couplings=couplings, crossings=crossings)


def main(argv: list[str] | None = None) -> int:
    """``softvr build-model PARTS.toml [-o MODEL.npz]``."""
    parser = argparse.ArgumentParser(prog="softvr build-model",
                                     description="Build a simulation model from part meshes (thesis 5.2).")
    parser.add_argument("parts", help="parts file (TOML, format 'softvr-parts 1')")
    parser.add_argument("-o", "--out", help="model file to write (default: PARTS with .model.npz)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    model = build_model(args.parts, progress=not args.quiet)
    out = Path(args.out) if args.out else Path(args.parts).with_suffix(".model.npz")
    model.save(out)
    for p in model.parts:
        s = p.spec
        size = f"{len(p.tets)} tets" if p.soft else f"{p.mass:.3g} kg"
        print(f"  {s.name:<20} {s.kind:<9} render {len(p.render_triangles):>6} tris, collision "
              f"{len(p.collision_triangles):>5} tris, {size}")
    print(f"  {len(model.couplings)} couplings, "
          f"{sum(len(s) for _, s in model.couplings)} springs")
    if model.crossings:
        print("  still crossing after the collision-free start: "
              + ", ".join(f"{k} ({v} triangle pairs)" for k, v in model.crossings.items()))
    else:
        print("  collision-free start: no crossing triangles")
    print(f"wrote {out}")
    return 0
