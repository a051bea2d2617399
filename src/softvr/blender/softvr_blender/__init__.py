"""softvr for Blender: mark objects for simulation, check the scene, export it, play it.

Objects get softvr custom properties (``softvr_type``, ``softvr_young``, ...), which Blender's
glTF exporter writes as extras: the exported ``.glb`` is a softvr scene as is (softvr's
``softvr.scene.gltf`` reads it). Kinematic bodies and tools move as their location keyframes;
couplings are properties of one of the two objects (*Pick coupling vertices* writes them);
sensors are properties of the body they read (*Add sensor*: ``softvr_sensor_<kind>`` holds the
sensor's name, ``softvr_sensor_contact_force_other`` a contact sensor's other body). The
add-on only edits those properties and runs the exporter and the ``softvr`` command (``softvr
check``, ``view``, ``tetmesh``, ``cave preview``); nothing else is needed in Blender.
"""

bl_info = {
    "name": "softvr",
    "author": "softvr developers",
    "version": (0, 2, 0),
    "blender": (4, 2, 0),
    "location": "Properties > Object / Scene > softvr",
    "description": "Mark objects as rigid, FEM, cloth, fixed, kinematic or tool bodies for softvr; couple them, "
                   "preview their tet meshes; check, export and play the scene",
    "category": "Physics",
}

import os
import shutil
import subprocess
import tempfile

import bpy
from bpy.props import EnumProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ExportHelper

KINDS = [("fem", "FEM (soft)", "Co-rotational finite elements on the object's tet mesh"),
         ("rigid", "Rigid", "A rigid body of the closed mesh"),
         ("cloth", "Cloth", "A mass-spring cloth of the mesh's triangles"),
         ("fixed", "Fixed", "A static obstacle"),
         ("kinematic", "Kinematic", "Moved by its location keyframes (holds still without), pushes what it meets"),
         ("tool", "Tool", "A rigid body on a spring to a hand that follows its location keyframes (haptics)"),
         ("none", "Not simulated", "Scenery: drawn, not simulated")]

#: Properties each kind needs (SI units), set when an object is marked and missing.
DEFAULTS = {
    "fem": {"softvr_young": 3.0e4, "softvr_poisson": 0.4, "softvr_density": 1000.0, "softvr_cells": 0.02,
            "softvr_alpha": 1.0, "softvr_beta": 0.002},
    "rigid": {"softvr_density": 1000.0},
    "cloth": {"softvr_area_density": 0.2, "softvr_stretch": 200.0, "softvr_shear": 20.0, "softvr_bend": 1.0,
              "softvr_damping": 0.05},
    "fixed": {},
    "kinematic": {},
    "tool": {"softvr_density": 1000.0, "softvr_stiffness": 300.0, "softvr_damping": 2.0, "softvr_haptics": False},
}
#: A scene's properties when its first object is marked; modelled objects often overlap a
#: little, so soft ones are pushed apart before the first step (thesis 5.2.3).
SCENE_DEFAULTS = {"softvr_dt": 0.005, "softvr_steps_per_frame": 4, "softvr_frames": 100, "softvr_friction": 0.5,
                  "softvr_display": "cube", "softvr_collision_free_start": True}
PREVIEW_IMAGE = "softvr CAVE preview"
#: What a sensor reads every frame (softvr.scene SENSOR_KINDS; tests/scene/test_blender.py
#: checks that the two lists agree): one of each kind per body.
SENSOR_KINDS = [("contact_force", "Contact force", "The contact force on the body [N] (from one other body, "
                 "\"static\" geometry, or all)"),
                ("coupling_force", "Coupling force", "The force of the body's couplings on it [N]"),
                ("position", "Position", "The body's centre [m]"),
                ("hand_force", "Hand force", "A tool's force on the hand holding its haptic device [N]")]
#: A contact sensor's other side: every static geometry (planes, static spheres, fixed meshes).
STATIC = "static"
#: Adhesion a surface gets with "Make adhesive" (softvr.contact.Adhesion; wet tissue, thesis ch. 4).
ADHESION_DEFAULTS = {"softvr_adhesion_stiffness": 1.0e7, "softvr_adhesion_max_energy": 0.4,
                     "softvr_adhesion_viscosity": 0.2, "softvr_adhesion_debond_gap": 0.003}


def _softvr_command(context):
    path = context.preferences.addons[__name__].preferences.softvr_command
    return path or shutil.which("softvr") or "softvr"


def _export(filepath):
    scene = bpy.context.scene
    # The simulation's t = 0 is the scene's start frame, in the exporter's animation seconds.
    scene["softvr_start_time"] = scene.frame_start / (scene.render.fps * scene.render.fps_base)
    bpy.ops.export_scene.gltf(filepath=filepath, export_format="GLB", export_extras=True)


def _export_temporary():
    """Export the scene to a new temporary ``.glb``; returns its path."""
    path = os.path.join(tempfile.mkdtemp(prefix="softvr-"), "scene.glb")
    _export(path)
    return path


def _run_softvr(operator, context, *args):
    """Run ``softvr ARGS``; on failure report its last error line. Returns whether it worked."""
    done = subprocess.run([_softvr_command(context), *args], capture_output=True, text=True)
    if done.returncode != 0:
        lines = (done.stderr or done.stdout).strip().splitlines()
        operator.report({"ERROR"}, lines[-1] if lines else f"softvr {args[0]} failed ({done.returncode})")
    return done.returncode == 0


class SOFTVR_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = __name__
    softvr_command: StringProperty(name="softvr command", subtype="FILE_PATH",
                                   description="The softvr executable (default: found on PATH)")

    def draw(self, context):
        self.layout.prop(self, "softvr_command")


class SOFTVR_OT_mark(bpy.types.Operator):
    """Mark the selected mesh objects as softvr bodies of one kind"""
    bl_idname = "softvr.mark"
    bl_label = "Mark for softvr"
    bl_options = {"REGISTER", "UNDO"}
    kind: EnumProperty(name="Kind", items=KINDS, default="fem")

    def execute(self, context):
        marked = 0
        for obj in context.selected_objects:
            if obj.type != "MESH":
                continue
            if self.kind == "none":
                for key in [k for k in obj.keys() if k.startswith("softvr_")]:
                    del obj[key]
                continue
            obj["softvr_type"] = self.kind
            # A re-marked object drops the other kinds' properties: softvr refuses an object that
            # carries keys of another type (a rigid body with softvr_young), so they cannot linger.
            foreign = {k for kind in DEFAULTS for k in DEFAULTS[kind]} - set(DEFAULTS[self.kind])
            for key in foreign & set(obj.keys()):
                del obj[key]
            for key, value in DEFAULTS[self.kind].items():
                if key not in obj:
                    obj[key] = value
            marked += 1
        for key, value in SCENE_DEFAULTS.items():
            if key not in context.scene:
                context.scene[key] = value
        self.report({"INFO"}, f"softvr: {marked} objects marked {self.kind}")
        return {"FINISHED"}


class SOFTVR_OT_pick_coupling(bpy.types.Operator):
    """Couple the active object at its selected vertices (their world positions) to the other
    selected object"""
    bl_idname = "softvr.pick_coupling"
    bl_label = "Pick coupling vertices"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        obj = context.active_object
        if obj is None or obj.type != "MESH":
            self.report({"ERROR"}, "softvr: the active object must be a mesh with selected vertices")
            return {"CANCELLED"}
        if obj.mode == "EDIT":
            # Edit mode keeps the selection in its own mesh: switch out to read it, then back.
            bpy.ops.object.mode_set(mode="OBJECT")
            points = [obj.matrix_world @ v.co for v in obj.data.vertices if v.select]
            bpy.ops.object.mode_set(mode="EDIT")
        else:
            points = [obj.matrix_world @ v.co for v in obj.data.vertices if v.select]
        if not points:
            self.report({"ERROR"}, f"softvr: no vertices of {obj.name!r} selected (select them in edit mode)")
            return {"CANCELLED"}
        # Blender's world coordinates (z up) are softvr's.
        obj["softvr_coupling_points"] = [float(c) for p in points for c in p]
        if "softvr_coupling_radius" in obj:
            del obj["softvr_coupling_radius"]  # points instead of a radius
        others = [o for o in context.selected_objects if o != obj]
        if len(others) == 1:
            obj["softvr_couple_to"] = others[0].name
        if "softvr_coupling_stiffness" not in obj:
            obj["softvr_coupling_stiffness"] = 2000.0
        to = obj.get("softvr_couple_to")
        if to is None:
            self.report({"WARNING"}, f"softvr: {len(points)} coupling points on {obj.name!r}; select the object to "
                                     "couple to as well (or set softvr_couple_to)")
        else:
            self.report({"INFO"}, f"softvr: {len(points)} coupling points on {obj.name!r}, coupled to {to!r}")
        return {"FINISHED"}


def _write_obj(obj, depsgraph, path):
    """The object's evaluated mesh in world coordinates as a Wavefront OBJ."""
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        world = obj.matrix_world
        with open(path, "w") as f:
            for v in mesh.vertices:
                x, y, z = world @ v.co
                f.write(f"v {x!r} {y!r} {z!r}\n")
            for polygon in mesh.polygons:
                f.write("f " + " ".join(str(i + 1) for i in polygon.vertices) + "\n")
    finally:
        evaluated.to_mesh_clear()


class SOFTVR_OT_preview_tets(bpy.types.Operator):
    """Show the tet mesh softvr builds for each selected FEM object (its cubes of softvr_cells),
    as a wire object "<name> tets" (not exported as a body)"""
    bl_idname = "softvr.preview_tets"
    bl_label = "Preview tet mesh"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        import numpy as np

        fem = [o for o in context.selected_objects if o.type == "MESH" and o.get("softvr_type") == "fem"]
        if not fem:
            self.report({"ERROR"}, "softvr: select objects marked FEM")
            return {"CANCELLED"}
        folder = tempfile.mkdtemp(prefix="softvr-tets-")
        depsgraph = context.evaluated_depsgraph_get()
        summary = []
        for obj in fem:
            surface, out = os.path.join(folder, "surface.obj"), os.path.join(folder, "tets.npz")
            _write_obj(obj, depsgraph, surface)
            cells = float(obj.get("softvr_cells", DEFAULTS["fem"]["softvr_cells"]))
            if not _run_softvr(self, context, "tetmesh", surface, "--cell-size", repr(cells), "-o", out):
                return {"CANCELLED"}
            with np.load(out) as f:
                nodes, edges = f["nodes"], f["edges"]
            name = f"{obj.name} tets"
            old = bpy.data.objects.get(name)
            if old is not None:
                old_mesh = old.data
                bpy.data.objects.remove(old)
                if old_mesh is not None and old_mesh.users == 0:
                    bpy.data.meshes.remove(old_mesh)
            mesh = bpy.data.meshes.new(name)
            mesh.from_pydata(nodes.tolist(), edges.tolist(), [])
            mesh.update()
            preview = bpy.data.objects.new(name, mesh)  # nodes in world coordinates: identity transform
            (obj.users_collection[0] if obj.users_collection else context.scene.collection).objects.link(preview)
            preview.display_type = "WIRE"
            preview.hide_render = True  # a look, not part of the scene: no softvr properties, no faces
            summary.append(f"{obj.name}: {len(nodes)} nodes, {len(edges)} edges")
        self.report({"INFO"}, "softvr tets: " + "; ".join(summary))
        return {"FINISHED"}


class SOFTVR_OT_adhesive(bpy.types.Operator):
    """Make the selected bodies' surfaces adhesive (or, with Off, not)"""
    bl_idname = "softvr.adhesive"
    bl_label = "Make adhesive"
    bl_options = {"REGISTER", "UNDO"}
    on: bpy.props.BoolProperty(name="On", default=True)

    def execute(self, context):
        changed = 0
        for obj in context.selected_objects:
            if "softvr_type" not in obj:
                continue
            if self.on:
                for key, value in ADHESION_DEFAULTS.items():
                    obj[key] = obj.get(key, value)
            else:
                for key in [k for k in obj.keys() if k.startswith("softvr_adhesion_")]:
                    del obj[key]
            changed += 1
        self.report({"INFO"}, f"softvr: {changed} bodies {'adhesive' if self.on else 'not adhesive'}")
        return {"FINISHED"}


class SOFTVR_OT_add_sensor(bpy.types.Operator):
    """Add a sensor of one kind to the active body (a contact force sensor reads the contacts
    with the other selected object only, when there is one)"""
    bl_idname = "softvr.add_sensor"
    bl_label = "Add sensor"
    bl_options = {"REGISTER", "UNDO"}
    kind: EnumProperty(name="Kind", items=SENSOR_KINDS, default="position")
    name: StringProperty(name="Name", description="The sensor's name in the metrics and plots (default: "
                                                  "<object> <kind>)")
    other: StringProperty(name="Other", description=f"contact force only: the other body's name or {STATIC!r} "
                                                    f"(default: the other selected object, {STATIC!r} for a fixed one, "
                                                    "else every contact)")

    def execute(self, context):
        obj = context.active_object
        if obj is None or obj.get("softvr_type") in (None, "fixed"):
            self.report({"ERROR"}, "softvr: the active object must be a body marked for softvr (not fixed: a static "
                                   "obstacle) to carry a sensor")
            return {"CANCELLED"}
        name = self.name or f"{obj.name} {self.kind.replace('_', ' ')}"
        obj[f"softvr_sensor_{self.kind}"] = name
        if self.kind == "contact_force":
            # A fixed object is static geometry (a triangle mesh obstacle), not a body softvr names.
            others = [STATIC if o.get("softvr_type") == "fixed" else o.name for o in context.selected_objects
                      if o != obj]
            other = self.other or (others[0] if len(others) == 1 else "")
            if other:
                obj["softvr_sensor_contact_force_other"] = other
            elif "softvr_sensor_contact_force_other" in obj:
                del obj["softvr_sensor_contact_force_other"]
        self.report({"INFO"}, f"softvr: sensor {name!r} ({self.kind}) on {obj.name!r}")
        return {"FINISHED"}


class SOFTVR_OT_remove_sensor(bpy.types.Operator):
    """Remove the active body's sensor of one kind"""
    bl_idname = "softvr.remove_sensor"
    bl_label = "Remove sensor"
    bl_options = {"REGISTER", "UNDO"}
    kind: EnumProperty(name="Kind", items=SENSOR_KINDS, default="position")

    def execute(self, context):
        obj = context.active_object
        keys = [f"softvr_sensor_{self.kind}"] + (["softvr_sensor_contact_force_other"]
                                                  if self.kind == "contact_force" else [])
        if obj is None or keys[0] not in obj:
            self.report({"WARNING"}, f"softvr: no {self.kind} sensor on the active object")
            return {"CANCELLED"}
        for key in keys:
            if key in obj:
                del obj[key]
        return {"FINISHED"}


def _draw_sensors(layout, obj):
    """The body's sensors (name and, for a contact force, its other side; each editable) and
    the buttons that add or remove one of each kind."""
    box = layout.box()
    box.label(text="Sensors")
    for kind, label, _ in SENSOR_KINDS:
        row = box.row(align=True)
        key = f"softvr_sensor_{kind}"
        if key in obj:
            row.prop(obj, f'["{key}"]', text=label)
            if kind == "contact_force" and "softvr_sensor_contact_force_other" in obj:
                row.prop(obj, '["softvr_sensor_contact_force_other"]', text="with")
            row.operator("softvr.remove_sensor", text="", icon="X").kind = kind
        else:
            row.operator("softvr.add_sensor", text=f"Add {label.lower()} sensor").kind = kind


class SOFTVR_OT_export(bpy.types.Operator, ExportHelper):
    """Export the scene as a softvr scene (glTF binary with softvr extras)"""
    bl_idname = "softvr.export"
    bl_label = "Export softvr scene"
    filename_ext = ".glb"

    def execute(self, context):
        _export(self.filepath)
        self.report({"INFO"}, f"softvr: exported {self.filepath}")
        return {"FINISHED"}


class SOFTVR_OT_check(bpy.types.Operator):
    """Export to a temporary file and run softvr check on it"""
    bl_idname = "softvr.check"
    bl_label = "Check with softvr"

    def execute(self, context):
        done = subprocess.run([_softvr_command(context), "check", _export_temporary()], capture_output=True,
                              text=True)
        # Every line: what the collision-free start pushed and the summary, or every problem
        # (the error and its list, after any library warnings on stderr).
        if done.returncode == 0:
            lines = done.stdout.strip().splitlines()
        else:
            lines = done.stderr.strip().splitlines()
            first = next((i for i, line in enumerate(lines) if line.startswith("softvr ")), 0)
            lines = lines[first:] or ["softvr check failed"]
        for line in lines:
            self.report({"INFO"} if done.returncode == 0 else {"ERROR"}, line)
        return {"FINISHED"} if done.returncode == 0 else {"CANCELLED"}


class SOFTVR_OT_play(bpy.types.Operator):
    """Export to a temporary file and play it in a softvr window"""
    bl_idname = "softvr.play"
    bl_label = "Play in softvr"

    def execute(self, context):
        subprocess.Popen([_softvr_command(context), "view", _export_temporary()])
        return {"FINISHED"}


class SOFTVR_OT_cave_preview(bpy.types.Operator):
    """Simulate the scene a few frames and render every screen of the CAVE display (the scene's
    softvr_display) unfolded into one picture: the image named softvr CAVE preview"""
    bl_idname = "softvr.cave_preview"
    bl_label = "Play on the CAVE preview"
    frames: IntProperty(name="Frames", default=30, min=1, description="frames to simulate before the picture")

    def execute(self, context):
        display = str(context.scene.get("softvr_display", SCENE_DEFAULTS["softvr_display"]))
        glb, out = _export_temporary(), tempfile.mkdtemp(prefix="softvr-cave-")
        if not _run_softvr(self, context, "cave", "preview", display, glb, "--frames", str(self.frames),
                           "--out", out, "--quiet"):
            return {"CANCELLED"}
        old = bpy.data.images.get(PREVIEW_IMAGE)
        if old is not None:
            bpy.data.images.remove(old)
        image = bpy.data.images.load(os.path.join(out, "cave_preview.png"))
        image.name = PREVIEW_IMAGE
        image.pack()  # kept in the .blend: the temporary folder may go
        width, height = image.size
        self.report({"INFO"}, f"softvr: {display} after {self.frames} frames, image {PREVIEW_IMAGE!r} "
                              f"({width} x {height}; Image Editor)")
        return {"FINISHED"}


class SOFTVR_PT_object(bpy.types.Panel):
    bl_label = "softvr"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    def draw(self, context):
        layout, obj = self.layout, context.object
        grid = layout.grid_flow(columns=3, align=True)
        for kind, label, _ in KINDS:
            grid.operator("softvr.mark", text=label).kind = kind
        row = layout.row()
        row.operator("softvr.pick_coupling")
        row.operator("softvr.preview_tets")
        row = layout.row(align=True)
        row.operator("softvr.adhesive", text="Make adhesive").on = True
        row.operator("softvr.adhesive", text="Not adhesive").on = False
        if obj is None:
            return
        for key in sorted(k for k in obj.keys() if k.startswith("softvr_") and not k.startswith("softvr_sensor_")):
            layout.prop(obj, f'["{key}"]', text=key[len("softvr_"):])
        if obj.get("softvr_type") not in (None, "fixed"):
            _draw_sensors(layout, obj)


class SOFTVR_PT_scene(bpy.types.Panel):
    bl_label = "softvr"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "scene"

    def draw(self, context):
        layout = self.layout
        for key in sorted(k for k in context.scene.keys() if k.startswith("softvr_")):
            layout.prop(context.scene, f'["{key}"]', text=key[len("softvr_"):])
        row = layout.row()
        row.operator("softvr.check")
        row.operator("softvr.export")
        row.operator("softvr.play")
        layout.operator("softvr.cave_preview")


CLASSES = (SOFTVR_AddonPreferences, SOFTVR_OT_mark, SOFTVR_OT_adhesive, SOFTVR_OT_pick_coupling, SOFTVR_OT_preview_tets,
           SOFTVR_OT_add_sensor, SOFTVR_OT_remove_sensor, SOFTVR_OT_export, SOFTVR_OT_check, SOFTVR_OT_play, SOFTVR_OT_cave_preview, SOFTVR_PT_object, SOFTVR_PT_scene)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
