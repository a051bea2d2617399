"""Seeded mutators for the fuzz suite: hostile TOML / JSON values, structural and byte-level
mutations of valid input files. Everything is drawn from a ``random.Random(seed)``, so a
failing input is reproduced by its seed and index."""

from __future__ import annotations

import json
import math
import random
import tomllib

__all__ = ["HOSTILE", "MILD", "byte_mutants", "mutate_tree", "paths_of", "toml_text"]


def _deep_list(depth: int):
    value: list = []
    for _ in range(depth):
        value = [value]
    return value


def _deep_table(depth: int):
    value: dict = {"x": 1}
    for _ in range(depth):
        value = {"x": value}
    return value


#: Values an attacker or a broken exporter writes where softvr expects something else: wrong
#: types, huge and negative counts, non-finite numbers, NUL bytes, long names, paths out.
HOSTILE = [
    [], [1, 2], [[1, 2, 3]], {}, {"a": 1}, 1.5, 0, -1, -5, 1, 2, 3, 4096, 100000, 1000000, 10 ** 9, 2 ** 31,
    2 ** 63 - 1, -(2 ** 63), 1e5, 1e6, 1e18, 1e30, 1e308, -1e308, 5e-324, float("nan"), float("inf"),
    float("-inf"), True, False, "", "x", "a\x00b", "a" * 300, "5 mm", "../../../../etc/passwd", "/etc/passwd",
    "/dev/zero", "fifo.obj", "fifo.toml", "fifo.bin", "fifo.vtu", "missing.ply", "é\u202e", [1e308] * 3,
    [float("nan")] * 3, [0, 0, 0], [1, 2, 3, 4], ["a", "b", "c"], [None] if False else [[]],
    _deep_list(40), _deep_table(40), _deep_list(200), list(range(2000)),
]


#: Values of the right types at the edges of their ranges: mutants that mostly pass the readers
#: and reach what builds, renders or allocates from them.
MILD = [0, 1, 2, 3, 8, 63, 64, 65, 0.0, 1e-6, 0.001, 0.01, 0.5, 2.0, 100.0, 1e4, -0.5, -1e4, True,
        [0.0, 0.0, 1.0], [1e-3, 1e-3, 1e-3], [100.0, 100.0, 100.0], [0.0, 0.0, 0.0], [64, 64], [1, 1]]


def paths_of(tree, prefix=()):
    """Every (key path) of a TOML / JSON tree, tables and lists included."""
    out = [prefix] if prefix else []
    if isinstance(tree, dict):
        for k, v in tree.items():
            out += paths_of(v, prefix + (k,))
    elif isinstance(tree, list):
        for i, v in enumerate(tree[:8]):
            out += paths_of(v, prefix + (i,))
    return out


def _set(tree, path, value):
    node = tree
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value


def _copy(tree):
    return json.loads(json.dumps(tree))


def mutate_tree(tree, rng: random.Random, *, extra=(), count: int = 1, pool=None):
    """A deep copy of ``tree`` with ``count`` random paths set to values of ``pool`` (default
    :data:`HOSTILE`), deleted, or duplicated (list items); ``extra`` adds values specific to
    the format."""
    tree = _copy(tree)
    pool = (HOSTILE if pool is None else pool) + list(extra)
    for _ in range(count):
        paths = paths_of(tree)
        if not paths:
            break
        path = rng.choice(paths)
        action = rng.random()
        parent = tree
        for key in path[:-1]:
            parent = parent[key]
        if action < 0.08 and isinstance(parent, dict):
            del parent[path[-1]]
        elif action < 0.12 and isinstance(parent, list):
            parent.append(_copy(parent[path[-1]]))  # duplicates: names, nodes twice
        else:
            value = rng.choice(pool)
            _set(tree, path, value if not isinstance(value, (list, dict)) else _copy_value(value))
    return tree


def _copy_value(value):
    try:
        return _copy(value)
    except (RecursionError, ValueError):  # deep or non-finite values: shared is fine (written once)
        return value


def _key(k: str) -> str:
    return json.dumps(k, ensure_ascii=True)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=True)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_text(tree: dict) -> str:
    """TOML for a tree: scalars and inline values first, then [tables] and [[arrays]]."""
    lines: list[str] = []
    _emit(tree, (), lines)
    return "\n".join(lines) + "\n"


def _emit(table: dict, prefix: tuple, lines: list) -> None:
    def is_tables(v):
        return isinstance(v, list) and v and all(isinstance(x, dict) for x in v)

    for k, v in table.items():
        if not isinstance(v, dict) and not is_tables(v):
            lines.append(f"{_key(k)} = {_value(v)}")
    for k, v in table.items():
        name = ".".join(_key(p) for p in prefix + (k,))
        if isinstance(v, dict):
            lines.append(f"[{name}]")
            _emit(v, prefix + (k,), lines)
        elif is_tables(v):
            for item in v:
                lines.append(f"[[{name}]]")
                _emit_inline_only(item, lines)


def _emit_inline_only(table: dict, lines: list) -> None:
    # An array-of-tables item: everything inline (sub-tables as inline tables), one level.
    for k, v in table.items():
        lines.append(f"{_key(k)} = {_value(v)}")


def byte_mutants(data: bytes, rng: random.Random, n: int) -> list[bytes]:
    """``n`` byte-level mutants: truncations, flipped bytes, inserted NUL / invalid UTF-8,
    repeated chunks, deep brackets."""
    out = []
    for _ in range(n):
        kind = rng.randrange(7)
        b = bytearray(data)
        if kind == 0 and b:
            b = b[:rng.randrange(len(b))]
        elif kind == 1 and b:
            for _ in range(rng.randint(1, 8)):
                b[rng.randrange(len(b))] = rng.randrange(256)
        elif kind == 2:
            at = rng.randrange(len(b) + 1)
            b[at:at] = rng.choice([b"\x00", b"\xff\xfe", b"\xc3", b"\xed\xa0\x80", b"\r", b"\x1b"])
        elif kind == 3 and b:
            at, size = rng.randrange(len(b)), rng.randint(1, 64)
            b[at:at] = bytes(b[at:at + size]) * rng.randint(2, 50)
        elif kind == 4:
            depth = rng.choice([100, 1000, 5000])
            b += b"\ndeep = " + b"[" * depth + b"]" * depth + b"\n"
        elif kind == 5:
            depth = rng.choice([100, 1000, 5000])
            b += b"\ndeep = " + b"{a = " * depth + b"1" + b"}" * depth + b"\n"
        else:
            b += b"\nhuge = " + b"9" * rng.choice([19, 30, 5000]) + b"\n"
        out.append(bytes(b))
    return out


def load_toml(path) -> dict:
    with open(path, "rb") as f:
        return tomllib.load(f)


def gltf_seed() -> tuple[dict, bytes]:
    """A small glTF physics scene as (JSON document, binary buffer): a fixed box, a rigid
    box with a material, a kinematic box with a translation animation, a light, scene extras
    (glTF y-up, as Blender writes it)."""
    import struct

    import numpy as np
    import trimesh

    scene = trimesh.Scene()
    for name, size in (("ground", (1.0, 0.1, 1.0)), ("crate", (0.2, 0.2, 0.2)), ("pusher", (0.1, 0.1, 0.1))):
        scene.add_geometry(trimesh.creation.box(size), node_name=name, geom_name=f"{name} mesh")
    data = scene.export(file_type="glb")
    length = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + length])
    binary = bytearray(data[28 + length:28 + length + struct.unpack("<I", data[20 + length:24 + length])[0]])
    extras = {"ground": {"softvr_type": "fixed"},
              "crate": {"softvr_type": "rigid", "softvr_density": 500.0, "softvr_collision_triangles": 12},
              "pusher": {"softvr_type": "kinematic"}}
    translations = {"ground": [0.0, -0.05, 0.0], "crate": [0.0, 0.2, 0.0], "pusher": [0.5, 0.2, 0.0]}
    for node in doc["nodes"]:
        node.pop("matrix", None)
        node.update(translation=translations[node["name"]], rotation=[0.0, 0.0, 0.0, 1.0],
                    extras=extras[node["name"]])
    pusher = next(i for i, n in enumerate(doc["nodes"]) if n["name"] == "pusher")

    def accessor(values, kind):
        values = np.asarray(values, "<f4")
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": values.nbytes})
        binary.extend(values.tobytes())
        binary.extend(b"\0" * (-len(binary) % 4))
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126,
                                 "count": len(values), "type": kind})
        return len(doc["accessors"]) - 1

    doc["animations"] = [{"channels": [{"sampler": 0, "target": {"node": pusher, "path": "translation"}}],
                          "samplers": [{"input": accessor([0.0, 1.0], "SCALAR"),
                                        "output": accessor([[0.5, 0.2, 0.0], [0.2, 0.2, 0.0]], "VEC3"),
                                        "interpolation": "LINEAR"}]}]
    doc["extensionsUsed"] = ["KHR_lights_punctual"]
    doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "directional", "intensity": 683.0}]}}
    doc["nodes"].append({"name": "sun", "translation": [1.0, 2.0, 1.0], "rotation": [-0.3, 0.0, 0.0, 0.95],
                         "extensions": {"KHR_lights_punctual": {"light": 0}}})
    doc["scenes"][0]["nodes"].append(len(doc["nodes"]) - 1)
    doc["scenes"][0]["extras"] = {"softvr_frames": 10, "softvr_dt": 0.005, "softvr_camera": "iso"}
    doc["buffers"][0]["byteLength"] = len(binary)
    return doc, bytes(binary)


def glb_bytes(doc: dict, binary: bytes | None) -> bytes:
    """A .glb of a JSON document and an optional BIN chunk."""
    import struct

    chunk = json.dumps(doc).encode()
    chunk += b" " * (-len(chunk) % 4)
    body = struct.pack("<I4s", len(chunk), b"JSON") + chunk
    if binary is not None:
        body += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def field_mutants(seeds: list, rng: random.Random, per_field: int, pool=None) -> list:
    """Every field of the ``seeds`` (trees), by its path with list indices folded
    (``body[].cells`` once, whichever body), set to ``per_field`` values of ``pool`` (default
    :data:`HOSTILE`) drawn without repeats: each field of each format meets the hostile values
    instead of the few a random mutant happens to draw."""
    pool = HOSTILE if pool is None else pool
    first: dict = {}
    for seed in seeds:
        for path in paths_of(seed):
            first.setdefault(tuple("#" if isinstance(k, int) else k for k in path), (seed, path))
    out = []
    for seed, path in first.values():
        for value in rng.sample(pool, per_field):
            tree = _copy(seed)
            _set(tree, path, value if not isinstance(value, (list, dict)) else _copy_value(value))
            out.append(tree)
    return out
