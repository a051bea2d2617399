"""glTF and GLB files as files: the container and the checks of its structure.

A .gltf file is JSON with its buffers and images beside it (or inside it, as ``data:`` URIs); a
.glb holds the JSON and one binary buffer as chunks. Before any reader (trimesh included) is given
one, :func:`check_gltf` checks every index, count, size and file the document states: accessors
within their buffer views, views within their buffers, buffer and image files regular files
inside the glTF's folder (:func:`softvr.files.inside_folder`), node names printable, the node
hierarchy a tree. Every problem is reported at once, each named by its JSON path
(``accessors[3].count``).

Both the model pipeline (:func:`softvr.model.load_mesh`, a glTF mesh) and the scene reader
(:mod:`softvr.scene.gltf`, a glTF scene with softvr properties) read glTF files, so the checks
live here, below both; what the softvr properties mean is the scene reader's.
"""

from __future__ import annotations

import struct
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from softvr.errors import InputError, raise_all
from softvr.files import MAX_ELEMENTS, MAX_FILE_BYTES, check_count, checked_file, inside_folder, load_json

__all__ = ["COMPONENTS", "check_gltf", "gltf_json"]

#: Components of an accessor of each type (glTF 2.0, 3.6.2.2).
COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _glb_chunks(path: Path) -> tuple[bytes, bytes | None]:
    """The JSON chunk and the BIN chunk (None when there is none) of a .glb file."""
    data = checked_file(path, "glb").read_bytes()
    if len(data) < 20 or data[:4] != b"glTF":
        raise InputError("glb", "a binary glTF file (magic 'glTF')", repr(data[:4]), source=str(path))
    chunks, at = [], 12
    while at + 8 <= len(data):
        length, kind = struct.unpack("<I4s", data[at:at + 8])
        chunks.append((kind, data[at + 8:at + 8 + length]))
        at += 8 + length
    if not chunks or chunks[0][0] != b"JSON":
        raise InputError("glb", "a JSON chunk first", repr(chunks[0][0] if chunks else b""), source=str(path))
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == b"BIN\x00" else None
    return chunks[0][1], binary


def gltf_json(path, with_binary: bool = False):
    """The JSON of a .gltf file or of a .glb's first chunk (and the .glb's BIN chunk, None when
    there is none, with ``with_binary``), its structure checked (:func:`check_gltf`)."""
    path, binary = Path(path), None
    if path.suffix.lower() == ".glb":
        data, binary = _glb_chunks(path)
    else:
        data = checked_file(path, "glTF").read_bytes()
    doc = load_json(data, "glTF JSON", str(path))
    _check_structure(doc, path, binary)
    return (doc, binary) if with_binary else doc


#: Most objects of one kind (nodes, accessors, ...) a glTF file may have.
_MAX_OBJECTS = 100_000
_ARRAYS = ("accessors", "animations", "buffers", "bufferViews", "cameras", "images", "materials", "meshes", "nodes",
           "samplers", "scenes", "skins", "textures")
_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_MAX_NAME = 255  # characters of a node name (Blender's limit is 63)
_MAX_ZEROS = 1 << 24  # components of an accessor without data (zeros): a morph target's size, not more


def _check_structure(doc, path: Path, binary: bytes | None) -> None:
    """Every index, count, size and file a glTF document states checked before anything reads
    it (trimesh included): one :class:`InputError` listing the problems, each named by its
    JSON path (``accessors[3].count``). Buffer and image files must be regular files inside
    the glTF's folder; accessors must fit their buffer views, views their buffers."""
    source = str(path)
    if not isinstance(doc, dict):
        raise InputError("glTF JSON", "an object", type(doc).__name__, source=source)
    out: list = []

    def bad(what, expected, found) -> None:
        out.append((what, expected, found if isinstance(found, str) else repr(found)[:200]))

    arrays = {}
    for key in _ARRAYS:
        value = doc.get(key, [])
        if not (isinstance(value, list) and len(value) <= _MAX_OBJECTS and all(isinstance(v, dict) for v in value)):
            bad(key, f"a list of at most {_MAX_OBJECTS} objects", type(value).__name__)
            value = []
        arrays[key] = value
    if out:
        raise_all(out, source, "glTF file")

    def index(table, key, where: str, of: str, *, required: bool = False) -> int | None:
        value = table[key] if isinstance(table, list) else table.get(key)
        if value is None and not required:
            return None
        if not (type(value) is int and 0 <= value < len(arrays[of])):
            bad(f"{where}[{key}]" if isinstance(table, list) else f"{where}.{key}",
                f"an index into {of} (0 .. {len(arrays[of]) - 1})", value if value is not None else "nothing")
            return None
        return value

    def integer(table: dict, key: str, where: str, low: int, high: int, default=None) -> int | None:
        value = table.get(key, default)
        if not (type(value) is int and low <= value <= high):
            bad(f"{where}.{key}", f"an integer in {low} .. {high}", value if value is not None else "nothing")
            return None
        return value

    def numbers(table: dict, key: str, where: str, size: int) -> None:
        value = table.get(key)
        if value is not None and not (isinstance(value, list) and len(value) == size and all(
                type(v) in (int, float) and np.isfinite(v) and abs(v) < 1e9 for v in value)):
            bad(f"{where}.{key}", f"{size} finite numbers", value)

    def extras(table: dict, where: str) -> None:
        for key in ("extras", "extensions"):
            if key in table and not isinstance(table[key], dict):
                bad(f"{where}.{key}", "an object", type(table[key]).__name__)

    if "scene" in doc:
        index(doc, "scene", "document", "scenes")
    sizes = []
    for i, b in enumerate(arrays["buffers"]):
        w = f"buffers[{i}]"
        length = integer(b, "byteLength", w, 1, MAX_FILE_BYTES)
        uri = b.get("uri")
        size = None
        if uri is None:
            size = len(binary) if binary is not None and i == 0 else None
            if size is None:
                bad(w, "a uri, or a .glb's BIN chunk (buffer 0)", "neither")
        elif not isinstance(uri, str):
            bad(f"{w}.uri", "a string", uri)
        elif uri.startswith("data:"):
            size = len(uri) * 3 // 4  # base64: an upper bound, checked again when decoded
        else:
            size = _file_size(path, uri, f"{w}.uri", bad)
        if length is not None and size is not None and size < length:
            bad(w, f"{length} bytes (byteLength)", f"{size} bytes")
        sizes.append(length if size is not None else None)
    for i, v in enumerate(arrays["bufferViews"]):
        w = f"bufferViews[{i}]"
        b = index(v, "buffer", w, "buffers", required=True)
        offset = integer(v, "byteOffset", w, 0, MAX_FILE_BYTES, default=0)
        length = integer(v, "byteLength", w, 1, MAX_FILE_BYTES)
        if "byteStride" in v:
            integer(v, "byteStride", w, 4, 252)
        size = sizes[b] if b is not None else None
        if offset is not None and length is not None and size is not None and offset + length > size:
            bad(w, f"bytes within buffers[{b}] ({size} bytes)", f"bytes {offset} .. {offset + length}")
    for i, a in enumerate(arrays["accessors"]):
        w = f"accessors[{i}]"
        component = a.get("componentType")
        if type(component) is not int or component not in _COMPONENT_BYTES:
            bad(f"{w}.componentType", f"one of {', '.join(map(str, _COMPONENT_BYTES))}", component)
        kind = a.get("type")
        if not isinstance(kind, str) or kind not in COMPONENTS:
            bad(f"{w}.type", " | ".join(COMPONENTS), kind)
        count = integer(a, "count", w, 1, MAX_ELEMENTS)
        offset = integer(a, "byteOffset", w, 0, MAX_FILE_BYTES, default=0)
        for key in ("min", "max"):
            value = a.get(key)
            if value is not None and not (isinstance(value, list) and len(value) <= 16 and all(
                    type(x) in (int, float) for x in value)):
                bad(f"{w}.{key}", "at most 16 numbers", value)
        if "sparse" in a:  # Blender writes shape keys so: its indices and values must fit their views
            sparse = a["sparse"]
            if not (isinstance(sparse, dict) and isinstance(sparse.get("indices"), dict)
                    and isinstance(sparse.get("values"), dict)):
                bad(f"{w}.sparse", "an object with count, indices and values", type(sparse).__name__)
            elif count is not None and isinstance(kind, str) and kind in COMPONENTS and \
                    type(component) is int and component in _COMPONENT_BYTES:
                n = integer(sparse, "count", f"{w}.sparse", 1, count)
                indices, values = sparse["indices"], sparse["values"]
                if indices.get("componentType") not in (5121, 5123, 5125) or type(indices["componentType"]) is not int:
                    bad(f"{w}.sparse.indices.componentType", "5121 | 5123 | 5125", indices.get("componentType"))
                    n = None
                for part, size in ((indices, _COMPONENT_BYTES.get(indices.get("componentType"), 4)),
                                   (values, _COMPONENT_BYTES[component] * COMPONENTS[kind])):
                    pw = f"{w}.sparse.{'indices' if part is indices else 'values'}"
                    sv = index(part, "bufferView", pw, "bufferViews", required=True)
                    so = integer(part, "byteOffset", pw, 0, MAX_FILE_BYTES, default=0)
                    length = arrays["bufferViews"][sv].get("byteLength") if sv is not None else None
                    if n is not None and so is not None and type(length) is int and so + n * size > length:
                        bad(pw, f"{n} entries within bufferViews[{sv}] ({length} bytes)",
                            f"bytes {so} .. {so + n * size}")
        v = index(a, "bufferView", w, "bufferViews")
        if count is None or offset is None or not isinstance(kind, str) or kind not in COMPONENTS or \
                type(component) is not int or component not in _COMPONENT_BYTES:
            continue
        element = _COMPONENT_BYTES[component] * COMPONENTS[kind]
        if v is None:
            try:
                check_count(count * COMPONENTS[kind], f"{w}.count", source, limit=_MAX_ZEROS)
            except InputError as exc:
                bad(exc.what, exc.expected, exc.found)
            continue
        view = arrays["bufferViews"][v]
        stride, length = view.get("byteStride") or element, view.get("byteLength")
        if type(stride) is int and type(length) is int and offset + stride * (count - 1) + element > length:
            bad(w, f"{count} {kind} within bufferViews[{v}] ({length} bytes)",
                f"bytes {offset} .. {offset + stride * (count - 1) + element}")
    for i, image in enumerate(arrays["images"]):
        w = f"images[{i}]"
        uri = image.get("uri")
        if uri is not None and (not isinstance(uri, str) or not uri.startswith("data:")):
            _file_size(path, uri, f"{w}.uri", bad)
        index(image, "bufferView", w, "bufferViews")
    for i, texture in enumerate(arrays["textures"]):
        index(texture, "source", f"textures[{i}]", "images")
        index(texture, "sampler", f"textures[{i}]", "samplers")
    for i, material in enumerate(arrays["materials"]):
        _texture_refs(material, f"materials[{i}]", len(arrays["textures"]), bad)
    for i, mesh in enumerate(arrays["meshes"]):
        w = f"meshes[{i}]"
        primitives = mesh.get("primitives")
        if not (isinstance(primitives, list) and primitives and all(isinstance(p, dict) for p in primitives)):
            bad(f"{w}.primitives", "a list of primitive objects", type(primitives).__name__)
            continue
        for j, primitive in enumerate(primitives):
            pw = f"{w}.primitives[{j}]"
            attributes = primitive.get("attributes")
            if not isinstance(attributes, dict) or "POSITION" not in attributes:
                bad(f"{pw}.attributes", "an object with POSITION", type(attributes).__name__)
            else:
                for name in attributes:
                    index(attributes, name, f"{pw}.attributes", "accessors", required=True)
            index(primitive, "indices", pw, "accessors")
            index(primitive, "material", pw, "materials")
            if "mode" in primitive:
                integer(primitive, "mode", pw, 0, 6)
            targets = primitive.get("targets", [])
            if not (isinstance(targets, list) and all(isinstance(t, dict) for t in targets)):
                bad(f"{pw}.targets", "a list of objects", type(targets).__name__)
            else:
                for k, target in enumerate(targets):
                    for name in target:
                        index(target, name, f"{pw}.targets[{k}]", "accessors", required=True)
    parent: dict = {}
    for i, node in enumerate(arrays["nodes"]):
        w = f"nodes[{i}]"
        name = node.get("name")
        if name is not None and not (isinstance(name, str) and len(name) <= _MAX_NAME and name.isprintable()):
            bad(f"{w}.name", f"a printable name of at most {_MAX_NAME} characters", name)
        extras(node, w)
        for key in ("mesh", "camera", "skin"):
            index(node, key, w, {"mesh": "meshes", "camera": "cameras", "skin": "skins"}[key])
        for key, size in (("matrix", 16), ("translation", 3), ("rotation", 4), ("scale", 3)):
            numbers(node, key, w, size)
        children = node.get("children", [])
        if not isinstance(children, list):
            bad(f"{w}.children", "a list of node indices", type(children).__name__)
            continue
        for k in range(len(children)):
            child = index(children, k, f"{w}.children", "nodes")
            if child is None:
                continue
            if child in parent or child == i:
                bad(f"{w}.children[{k}]", "a node with one parent (a tree)", f"node {child} again")
            else:
                parent[child] = i
        light = node.get("extensions", {}).get("KHR_lights_punctual") if isinstance(
            node.get("extensions"), dict) else None
        if light is not None and not isinstance(light, dict):
            bad(f"{w}.extensions.KHR_lights_punctual", "an object", type(light).__name__)
    for i in parent:  # a cycle of children has no root: following parents never ends
        seen, at = set(), i
        while at in parent and at not in seen:
            seen.add(at)
            at = parent[at]
        if at in seen:
            bad(f"nodes[{i}].children", "a tree of nodes", "a cycle")
            break
    for i, scene in enumerate(arrays["scenes"]):
        extras(scene, f"scenes[{i}]")
        roots = scene.get("nodes", [])
        if not isinstance(roots, list):
            bad(f"scenes[{i}].nodes", "a list of node indices", type(roots).__name__)
            continue
        for k in range(len(roots)):
            index(roots, k, f"scenes[{i}].nodes", "nodes")
    for i, skin in enumerate(arrays["skins"]):
        index(skin, "inverseBindMatrices", f"skins[{i}]", "accessors")
        joints = skin.get("joints", [])
        for k in range(len(joints) if isinstance(joints, list) else 0):
            index(joints, k, f"skins[{i}].joints", "nodes")
    for a, animation in enumerate(arrays["animations"]):
        w = f"animations[{a}]"
        samplers, channels = animation.get("samplers", []), animation.get("channels", [])
        if not (isinstance(samplers, list) and all(isinstance(x, dict) for x in samplers)
                and isinstance(channels, list) and all(isinstance(x, dict) for x in channels)):
            bad(w, "samplers and channels: lists of objects", "something else")
            continue
        for k, sampler in enumerate(samplers):
            index(sampler, "input", f"{w}.samplers[{k}]", "accessors", required=True)
            index(sampler, "output", f"{w}.samplers[{k}]", "accessors", required=True)
            if not isinstance(sampler.get("interpolation", "LINEAR"), str):
                bad(f"{w}.samplers[{k}].interpolation", "LINEAR | STEP | CUBICSPLINE", sampler["interpolation"])
        for k, channel in enumerate(channels):
            target = channel.get("target")
            if not isinstance(target, dict):
                bad(f"{w}.channels[{k}].target", "an object", type(target).__name__)
                continue
            index(target, "node", f"{w}.channels[{k}].target", "nodes")
            if not isinstance(target.get("path"), str):
                bad(f"{w}.channels[{k}].target.path", "translation | rotation | scale | weights", target.get("path"))
            if not (type(channel.get("sampler")) is int and 0 <= channel["sampler"] < len(samplers)):
                bad(f"{w}.channels[{k}].sampler", f"an index into the animation's {len(samplers)} samplers",
                    channel.get("sampler"))
    lights = doc.get("extensions", {}).get("KHR_lights_punctual", {}) if isinstance(doc.get("extensions", {}), dict) \
        else None
    if lights is None:
        bad("extensions", "an object", type(doc.get("extensions")).__name__)
    elif not (isinstance(lights, dict) and isinstance(lights.get("lights", []), list)
              and all(isinstance(x, dict) for x in lights.get("lights", []))):
        bad("extensions.KHR_lights_punctual.lights", "a list of light objects", type(lights).__name__)
    raise_all(out, source, "glTF file")


def _file_size(path: Path, uri: str, what: str, bad) -> int | None:
    """Size [bytes] of the regular file a buffer or image ``uri`` names inside the glTF's
    folder; None (and a problem) when it is outside, missing, or not a regular file."""
    try:
        file = checked_file(inside_folder(path.parent, unquote(uri), what, str(path)), what)
    except InputError as exc:
        bad(what, exc.expected, exc.found)
        return None
    return file.stat().st_size


def _texture_refs(table, where: str, textures: int, bad, depth: int = 0) -> None:
    """Every ``{"index": i}`` texture reference inside a material names one of the textures."""
    if depth > 8 or not isinstance(table, dict):
        return
    for key, value in table.items():
        if isinstance(value, dict):
            if key.endswith("Texture") and not (type(value.get("index")) is int and 0 <= value["index"] < textures):
                bad(f"{where}.{key}.index", f"an index into textures (0 .. {textures - 1})", value.get("index"))
            _texture_refs(value, f"{where}.{key}", textures, bad, depth + 1)


def check_gltf(path) -> None:
    """An :class:`InputError` when a .gltf / .glb file is not one trimesh may be given: bad
    JSON, or an index, count, size or buffer / image file that is out of range, outside its
    folder or not a regular file (the module docstring)."""
    gltf_json(path)
