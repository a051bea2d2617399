"""softvr for Blender: mark objects for simulation, check the scene, export it, play it.

Objects get softvr custom properties (``softvr_type``, ``softvr_young``, ...), which Blender's
glTF exporter writes as extras: the exported ``.glb`` is a softvr scene as is (softvr's
``softvr.scene.gltf`` reads it). The add-on only edits those properties and runs the exporter
and the ``softvr`` command; nothing else is needed in Blender.
"""

bl_info = {
    "name": "softvr",
    "author": "softvr developers",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "Properties > Object / Scene > softvr",
    "description": "Mark objects as rigid, FEM, cloth or fixed bodies for softvr; check, export and play the scene",
    "category": "Physics",
}

import os
import shutil
import subprocess
import tempfile

import bpy
from bpy.props import EnumProperty, StringProperty
from bpy_extras.io_utils import ExportHelper

KINDS = [("fem", "FEM (soft)", "Co-rotational finite elements on the object's tet mesh"),
         ("rigid", "Rigid", "A rigid body of the closed mesh"),
         ("cloth", "Cloth", "A mass-spring cloth of the mesh's triangles"),
         ("fixed", "Fixed", "A static obstacle"),
         ("none", "Not simulated", "Scenery: drawn, not simulated")]

#: Properties each kind needs (SI units), set when an object is marked and missing.
DEFAULTS = {
    "fem": {"softvr_young": 3.0e4, "softvr_poisson": 0.4, "softvr_density": 1000.0, "softvr_cells": 0.02,
            "softvr_alpha": 1.0, "softvr_beta": 0.002},
    "rigid": {"softvr_density": 1000.0},
    "cloth": {"softvr_area_density": 0.2, "softvr_stretch": 200.0, "softvr_shear": 20.0, "softvr_bend": 1.0,
              "softvr_damping": 0.05},
    "fixed": {},
}
SCENE_DEFAULTS = {"softvr_dt": 0.005, "softvr_steps_per_frame": 4, "softvr_frames": 100, "softvr_friction": 0.5}


def _softvr_command(context):
    path = context.preferences.addons[__name__].preferences.softvr_command
    return path or shutil.which("softvr") or "softvr"


def _export(filepath):
    bpy.ops.export_scene.gltf(filepath=filepath, export_format="GLB", export_extras=True)


def _export_temporary():
    """Export the scene to a new temporary ``.glb``; returns its path."""
    path = os.path.join(tempfile.mkdtemp(prefix="softvr-"), "scene.glb")
    _export(path)
    return path


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
            for key, value in DEFAULTS[self.kind].items():
                if key not in obj:
                    obj[key] = value
            marked += 1
        for key, value in SCENE_DEFAULTS.items():
            if key not in context.scene:
                context.scene[key] = value
        self.report({"INFO"}, f"softvr: {marked} objects marked {self.kind}")
        return {"FINISHED"}


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
        report = (done.stdout or done.stderr).strip().splitlines()
        self.report({"INFO"} if done.returncode == 0 else {"ERROR"}, report[-1] if report else "softvr check failed")
        return {"FINISHED"} if done.returncode == 0 else {"CANCELLED"}


class SOFTVR_OT_play(bpy.types.Operator):
    """Export to a temporary file and play it in a softvr window"""
    bl_idname = "softvr.play"
    bl_label = "Play in softvr"

    def execute(self, context):
        subprocess.Popen([_softvr_command(context), "view", _export_temporary()])
        return {"FINISHED"}


class SOFTVR_PT_object(bpy.types.Panel):
    bl_label = "softvr"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    def draw(self, context):
        layout, obj = self.layout, context.object
        row = layout.row(align=True)
        for kind, label, _ in KINDS:
            row.operator("softvr.mark", text=label).kind = kind
        for key in sorted(k for k in obj.keys() if k.startswith("softvr_")):
            layout.prop(obj, f'["{key}"]', text=key[len("softvr_"):])


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


CLASSES = (SOFTVR_AddonPreferences, SOFTVR_OT_mark, SOFTVR_OT_export, SOFTVR_OT_check, SOFTVR_OT_play,
           SOFTVR_PT_object, SOFTVR_PT_scene)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
