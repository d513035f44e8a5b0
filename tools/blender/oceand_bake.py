"""oceand for Blender: import an ocean-tap bake, or pull the live sea into a mesh.

Install: Edit > Preferences > Add-ons > Install..., pick this file, tick
"Import-Export: oceand". Then:

* File > Import > oceand bake (folder): a directory written by
    ocean-tap ws://HOST:8080 --format exr --cascades all --bound 0 --frames K --out DIR
  The add-on makes a grid whose vertices are the bake's samples (vertex (i, j)
  at X = x0 + i*S/M, Y = z0 + j*S/M: our x is Blender's X, our z its Y, our
  height its Z), and a Displace modifier (RGB to XYZ, UV coordinates, closest
  pixel) reading the image sequence vdisp_NNNN.exr, which holds the sum of every
  cascade (R = Dx, G = Dz, B = height). Blender frame f shows bake frame f: the
  scene's frame range is set to 1..K and its frame rate to the bake's, and the
  object's property "oceand_sim_time" is keyed at each frame with the frame's
  sim time. The modifier samples the bake at its own nodes, so the mesh is the
  sea at the samples (half-float precision) - not a filtered version of it.
* View3D > Sidebar > oceand > Live: connects to a daemon with the oceand Python
  package and rewrites the object's vertices with the summed sea a few times a
  second while Blender's UI runs (a timer; the network runs in a thread of the
  client). Debian's Blender runs the system Python, which finds the package when
  it is installed for it, or through the add-on's preference "oceand package
  folder" (the checkout's proto/python).

Blender's own Ocean modifier reads bakes only after a bake made in a GUI
session (its is_cached flag cannot be set from Python, and `blender -b` never
sets it), holds one cascade per modifier and samples bilinearly between
texels; the Displace route avoids all three. docs/operations.md says more.
"""
import glob
import json
import os
import sys

import bpy
import numpy as np
from bpy.props import FloatProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

bl_info = {
    "name": "oceand",
    "author": "oceand",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "File > Import > oceand bake; View3D > Sidebar > oceand",
    "description": "Import ocean-tap bakes (every cascade) and stream the live sea from an oceand daemon",
    "category": "Import-Export",
}


# ---- the mesh: one vertex per sample ----------------------------------------------

def grid_mesh(name, m, x0, z0, size):
    """An m x m grid of vertices, (i, j) at (x0 + i*size/m, z0 + j*size/m, 0), with
    quads between them and a UV map that puts vertex (i, j) at texel (i, j)'s centre."""
    me = bpy.data.meshes.new(name)
    t = np.arange(m, dtype=np.float64) * (size / m)
    yy, xx = np.meshgrid(z0 + t, x0 + t, indexing="ij")
    co = np.stack([xx.ravel(), yy.ravel(), np.zeros(m * m)], 1).astype(np.float32)
    me.vertices.add(m * m)
    me.vertices.foreach_set("co", co.ravel())
    j, i = np.meshgrid(np.arange(m - 1), np.arange(m - 1), indexing="ij")
    v0 = (j * m + i).ravel()
    quads = np.stack([v0, v0 + 1, v0 + m + 1, v0 + m], 1)
    nq = len(quads)
    me.loops.add(4 * nq)
    me.loops.foreach_set("vertex_index", quads.ravel().astype(np.int32))
    me.polygons.add(nq)
    me.polygons.foreach_set("loop_start", (np.arange(nq) * 4).astype(np.int32))
    me.polygons.foreach_set("loop_total", np.full(nq, 4, np.int32))
    uv = me.uv_layers.new(name="oceand")
    vi = quads.ravel()
    uvs = np.stack([(vi % m + 0.5) / m, (vi // m + 0.5) / m], 1).astype(np.float32)
    uv.data.foreach_set("uv", uvs.ravel())
    me.update(calc_edges=True)
    me.validate()
    return me


def read_bake(directory):
    """frame_NNNN.json of a bake directory, in frame order."""
    frames = sorted(glob.glob(os.path.join(directory, "frame_[0-9][0-9][0-9][0-9].json")))
    if not frames:
        raise ValueError(f"no frame_NNNN.json in {directory}: not an ocean-tap --format exr bake")
    metas = [json.load(open(f)) for f in frames]
    for k, m in enumerate(metas, start=1):
        if m.get("frame") != k or not os.path.exists(os.path.join(directory, f"vdisp_{k:04d}.exr")):
            raise ValueError(f"bake frame {k} is missing (frames must be 1, 2, ... with vdisp_NNNN.exr)")
    return metas


def import_bake(context, directory, name="oceand sea"):
    """Build the object, its Displace modifier and the timing. Returns the object."""
    metas = read_bake(directory)
    first = metas[0]
    m, size = int(first["side"]), float(first["patch_size"])
    x0, z0 = (first.get("origin") or [0.0, 0.0])[:2]
    obj = bpy.data.objects.new(name, grid_mesh(name, m, x0, z0, size))
    context.collection.objects.link(obj)

    img = bpy.data.images.load(os.path.join(directory, "vdisp_0001.exr"), check_existing=False)
    img.source = "SEQUENCE"
    img.colorspace_settings.name = "Non-Color"   # data, not colour: no view transform on it
    tex = bpy.data.textures.new(name + " displacement", type="IMAGE")
    tex.image = img
    tex.image_user.frame_start = 1
    tex.image_user.frame_offset = 0
    tex.image_user.frame_duration = len(metas)
    tex.image_user.use_auto_refresh = True
    tex.use_interpolation = False   # the vertex reads its own texel: no blend with the neighbours
    tex.use_mipmap = False
    tex.use_clamp = False           # displacements are negative as often as positive
    tex.extension = "EXTEND"
    mod = obj.modifiers.new("oceand", "DISPLACE")
    mod.texture = tex
    mod.texture_coords = "UV"
    mod.uv_layer = "oceand"
    mod.direction = "RGB_TO_XYZ"
    mod.space = "LOCAL"
    mod.mid_level = 0.0
    mod.strength = 1.0

    scene = context.scene
    scene.frame_start, scene.frame_end = 1, len(metas)
    if len(metas) > 1:
        dt = float(np.median(np.diff([mt["sim_time"] for mt in metas])))
        if dt > 0:
            fps = 1.0 / dt
            scene.render.fps, scene.render.fps_base = max(1, round(fps)), max(1, round(fps)) / fps
    obj["oceand_sim_time"] = float(first["sim_time"])
    obj["oceand_bake"] = directory
    for mt in metas:   # the sim time each Blender frame shows (constant between keys)
        obj["oceand_sim_time"] = float(mt["sim_time"])
        obj.keyframe_insert('["oceand_sim_time"]', frame=mt["frame"])
    for fc in obj.animation_data.action.fcurves:
        for kp in fc.keyframe_points:
            kp.interpolation = "CONSTANT"
    return obj


class OCEAND_OT_import_bake(bpy.types.Operator, ImportHelper):
    """Import a bake written by ocean-tap --format exr (a folder)"""
    bl_idname = "oceand.import_bake"
    bl_label = "Import oceand bake"
    bl_options = {"REGISTER", "UNDO"}
    filename_ext = ".json"
    filter_glob: StringProperty(default="frame_*.json", options={"HIDDEN"})
    directory: StringProperty(subtype="DIR_PATH")

    def execute(self, context):
        directory = self.directory or os.path.dirname(self.filepath)
        try:
            obj = import_bake(context, directory)
        except (ValueError, OSError, RuntimeError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        context.view_layer.objects.active = obj
        self.report({"INFO"}, f"oceand bake: {context.scene.frame_end} frames")
        return {"FINISHED"}


# ---- live -----------------------------------------------------------------------

def _client_module():
    """The oceand package: installed, in the folder of the add-on's preferences,
    or in proto/python of the checkout this file sits in (not when Blender
    installed a copy of it)."""
    try:
        import oceand
        return oceand
    except ImportError:
        pass
    folders = []
    addon = bpy.context.preferences.addons.get(__name__)
    if addon and addon.preferences.package_folder:
        folders.append(bpy.path.abspath(addon.preferences.package_folder))
    here = os.path.dirname(os.path.realpath(__file__))
    folders.append(os.path.normpath(os.path.join(here, "..", "..", "proto", "python")))
    for f in folders:
        if os.path.isfile(os.path.join(f, "oceand", "__init__.py")) and f not in sys.path:
            sys.path.insert(0, f)
    import oceand
    return oceand


class Live:
    """A connection whose summed surface is written into an object's vertices."""

    def __init__(self, url, m):
        oceand = _client_module()
        self.client = oceand.Client(url)
        self.client.subscribe(fields=["height", "dx", "dz"], bound=0.001, cascades="all", max_rate=10)
        self.m, self.last_seq, self.obj = m, None, None

    def make_object(self, context, name="oceand live"):
        s = self.client.surface()
        size = s.patch_sizes[0]
        self.obj = bpy.data.objects.new(name, grid_mesh(name, self.m, 0.0, 0.0, size))
        context.collection.objects.link(self.obj)
        self._write(s)
        return self.obj

    def _write(self, s):
        m, size = self.m, s.patch_sizes[0]
        t = np.arange(m) * (size / m)
        zz, xx = np.meshgrid(t, t, indexing="ij")
        co = np.stack([xx + s.grid("dx", m), zz + s.grid("dz", m), s.grid("height", m)], -1)
        self.obj.data.vertices.foreach_set("co", co.astype(np.float32).ravel())
        self.obj.data.update()
        self.obj["oceand_sim_time"] = float(s.sim_time)
        self.last_seq = s.seq

    def step(self):
        """Write the newest surface if there is one; returns its seq."""
        s = self.client.surface(newer_than=self.last_seq)
        self._write(s)
        return s.seq

    def close(self):
        self.client.close()


_live = {}


def _live_timer():
    live = _live.get("live")
    if live is None or live.obj is None or live.obj.name not in bpy.data.objects:
        return None
    try:
        live.step()
    except Exception as e:   # the daemon went away: stop the timer, say why
        print(f"oceand live: stopped: {e}")
        live.close()
        _live.pop("live", None)
        return None
    return bpy.context.scene.oceand_live_interval


class OCEAND_OT_live(bpy.types.Operator):
    """Start or stop pulling the live sea into a mesh"""
    bl_idname = "oceand.live"
    bl_label = "oceand Live"

    def execute(self, context):
        if "live" in _live:
            _live.pop("live").close()
            self.report({"INFO"}, "oceand live: stopped")
            return {"FINISHED"}
        try:
            live = Live(context.scene.oceand_url, context.scene.oceand_live_side)
            live.make_object(context)
        except Exception as e:
            self.report({"ERROR"}, f"oceand live: {e}")
            return {"CANCELLED"}
        _live["live"] = live
        bpy.app.timers.register(_live_timer, first_interval=context.scene.oceand_live_interval)
        return {"FINISHED"}


class OCEAND_PT_panel(bpy.types.Panel):
    bl_label = "oceand"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "oceand"

    def draw(self, context):
        col = self.layout.column()
        col.prop(context.scene, "oceand_url")
        col.prop(context.scene, "oceand_live_side")
        col.prop(context.scene, "oceand_live_interval")
        col.operator(OCEAND_OT_live.bl_idname, text="Stop live" if "live" in _live else "Live")
        col.operator(OCEAND_OT_import_bake.bl_idname)


def _menu_import(self, context):
    self.layout.operator(OCEAND_OT_import_bake.bl_idname, text="oceand bake (folder)")


class OCEAND_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = __name__
    package_folder: StringProperty(
        name="oceand package folder", subtype="DIR_PATH", default="",
        description="folder holding the oceand Python package (a checkout's proto/python), for Live")

    def draw(self, context):
        self.layout.prop(self, "package_folder")


_classes = (OCEAND_AP_preferences, OCEAND_OT_import_bake, OCEAND_OT_live, OCEAND_PT_panel)


def register():
    for c in _classes:
        bpy.utils.register_class(c)
    bpy.types.TOPBAR_MT_file_import.append(_menu_import)
    bpy.types.Scene.oceand_url = StringProperty(name="Daemon", default="ws://127.0.0.1:8080")
    bpy.types.Scene.oceand_live_side = IntProperty(name="Grid", default=128, min=2, max=2048,
                                                   description="vertices per side of the live mesh")
    bpy.types.Scene.oceand_live_interval = FloatProperty(name="Every (s)", default=0.1, min=0.02, max=10)


def unregister():
    if "live" in _live:
        _live.pop("live").close()
    bpy.types.TOPBAR_MT_file_import.remove(_menu_import)
    for c in reversed(_classes):
        bpy.utils.unregister_class(c)
    del bpy.types.Scene.oceand_url, bpy.types.Scene.oceand_live_side, bpy.types.Scene.oceand_live_interval
