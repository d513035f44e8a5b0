"""Runs inside Blender (blender -b --factory-startup --python THIS -- ADDON BAKE_DIR URL OUT_JSON):
installs the add-on through Blender's add-on preferences, imports the bake,
and for the first and last frame compares the evaluated vertices with the
daemon's exact surface (`query` at the displaced vertex's X, Y at that frame's
sim time: its height must be the vertex's Z and its source the undisplaced
vertex). Then one step of Live against the same daemon. Writes the errors as
JSON; exits non-zero when a check fails."""
import json
import os
import sys
import traceback

import bpy
import numpy as np

addon, bake, url, out = sys.argv[sys.argv.index("--") + 1:][:4]
here = os.path.dirname(os.path.abspath(__file__))
pkg_dir = os.path.normpath(os.path.join(here, "..", "..", "proto", "python"))
sys.path.insert(0, pkg_dir)
import oceand  # noqa: E402

RMS_MAX_M = 0.025   # the target: vertex displacement within 25 mm rms of query
POINTS = 256
result = {}


def check(cond, msg):
    if not cond:
        raise AssertionError(msg)


def evaluated(obj):
    dg = bpy.context.evaluated_depsgraph_get()
    me = obj.evaluated_get(dg).to_mesh()
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    obj.evaluated_get(dg).to_mesh_clear()
    return co.reshape(-1, 3).astype(np.float64)


def compare(sea, rest, moved, sim_time, rng):
    idx = rng.choice(len(rest), POINTS, replace=False)
    q = sea.query(moved[idx, :2], time=sim_time)
    hq = np.array([p["height"] for p in q["points"]])
    src = np.array([p["source"] for p in q["points"]])
    dz = moved[idx, 2] - hq
    dsrc = np.hypot(*(src - rest[idx, :2]).T)
    return {"height_rms_mm": float(np.sqrt(np.mean(dz ** 2)) * 1e3), "height_max_mm": float(np.abs(dz).max() * 1e3),
            "source_rms_mm": float(np.sqrt(np.mean(dsrc ** 2)) * 1e3)}


try:
    bpy.ops.preferences.addon_install(filepath=addon, overwrite=True)
    bpy.ops.preferences.addon_enable(module=os.path.splitext(os.path.basename(addon))[0])
    check(hasattr(bpy.ops.oceand, "import_bake"), "the add-on did not register its operator")
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    r = bpy.ops.oceand.import_bake(directory=bake)
    check(r == {"FINISHED"}, f"import_bake: {r}")
    obj = bpy.context.view_layer.objects.active
    metas = [json.load(open(os.path.join(bake, f))) for f in sorted(os.listdir(bake))
             if f.startswith("frame_") and f.endswith(".json")]
    scene = bpy.context.scene
    check((scene.frame_start, scene.frame_end) == (1, len(metas)), f"frame range {scene.frame_start}..{scene.frame_end}")
    rest = np.array([v.co[:] for v in obj.data.vertices], np.float64)
    rng = np.random.default_rng(5)
    with oceand.Client(url) as sea:
        for f in sorted({1, len(metas)}):
            scene.frame_set(f)
            check(abs(obj["oceand_sim_time"] - metas[f - 1]["sim_time"]) < 1e-3, f"frame {f}: oceand_sim_time")  # F-curves hold float32
            moved = evaluated(obj)
            check(np.abs(moved - rest).max() > 0.01, f"frame {f}: the modifier moved nothing")
            e = compare(sea, rest, moved, metas[f - 1]["sim_time"], rng)
            result[f"frame_{f}"] = e
            check(e["height_rms_mm"] <= RMS_MAX_M * 1e3, f"frame {f}: height {e['height_rms_mm']:.2f} mm rms of query")
            check(e["source_rms_mm"] <= RMS_MAX_M * 1e3, f"frame {f}: horizontal {e['source_rms_mm']:.2f} mm rms")
        # Blender's frame f is bake frame f: frame 1's sea is not frame K's.
        if len(metas) > 1:
            scene.frame_set(1)
            e = compare(sea, rest, evaluated(obj), metas[-1]["sim_time"], rng)
            result["frame_1_against_last_time"] = e
            check(e["height_rms_mm"] > 2 * RMS_MAX_M * 1e3 or e["source_rms_mm"] > 2 * RMS_MAX_M * 1e3,
                  "frame 1 matches the last frame's time: the comparison cannot tell frames apart")
    # Live: one step (a timer needs the UI's event loop, absent with -b), with the package
    # found through the add-on's preference, as a user of the installed add-on would.
    name = os.path.splitext(os.path.basename(addon))[0]
    mod = sys.modules[name]
    sys.path.remove(pkg_dir)
    for k in [k for k in sys.modules if k == "oceand" or k.startswith("oceand.")]:
        del sys.modules[k]
    bpy.context.preferences.addons[name].preferences.package_folder = pkg_dir
    oceand = mod._client_module()
    check(os.path.dirname(oceand.__file__) == os.path.join(pkg_dir, "oceand"), f"Live found {oceand.__file__}")
    live = mod.Live(url, 64)
    try:
        lobj = live.make_object(bpy.context)
        seq0 = live.last_seq
        live.step()
        check(live.last_seq > seq0, "Live.step() wrote no newer surface")
        co = np.empty(64 * 64 * 3, np.float32)
        lobj.data.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3).astype(np.float64)
        t = lobj["oceand_sim_time"]
        with oceand.Client(url) as sea:
            idx = np.random.default_rng(6).choice(len(co), 64, replace=False)
            q = sea.query(co[idx, :2], time=t)
        dz = co[idx, 2] - np.array([p["height"] for p in q["points"]])
        result["live"] = {"height_rms_mm": float(np.sqrt(np.mean(dz ** 2)) * 1e3)}
        check(result["live"]["height_rms_mm"] <= RMS_MAX_M * 1e3, f"live: {result['live']}")
    finally:
        live.close()
    result["ok"] = True
except Exception:
    traceback.print_exc()
    result["ok"] = False
json.dump(result, open(out, "w"), indent=1)
print(json.dumps(result))
sys.exit(0 if result["ok"] else 1)
