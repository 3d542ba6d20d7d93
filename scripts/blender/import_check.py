#!/usr/bin/env python3
"""Blender (PyPI `bpy`, pinned in scripts/blender/requirements.txt) imports `bake export`'s GLB;
the counts and the instances are checked against `bake dump --json --full` of the same pack.

    python scripts/blender/import_check.py SCENE.glb DUMP.json [--bake-light]

DUMP.json: `bake dump PACK --json --full --section instances` is enough for the instances; the
full `bake dump PACK --json` (any sections) gives the rest, so pass the output of
`bake dump PACK --json --full`. Checks, each against the dump (not against the GLB):
- meshes: one Blender mesh per `mesh` section that has instances (or every mesh section in a
  pack without an `instances` section), plus one for the terrain;
- materials: one per `material` section plus the terrain's;
- instances: per model, the objects that use its mesh, as many as the pack places; each one is
  matched to the instance record nearest its origin, and every vertex of the pack's mesh placed
  by that record (docs/CONVENTIONS.md: position + R_z(rotation) · scale · p) lies on one of the
  object's world-space vertices and back, within 1 mm (Blender turns glTF's Y-up back into
  Z-up, so bake's coordinates come back as they were);
- the sun: one sun lamp;
- with --bake-light: the terrain material's base colour reads the `<colour> x <light map>` image.
Prints a JSON summary; exit 0 when all hold, 1 otherwise, 3 when bpy cannot run.
"""
import json
import math
import sys

try:
    import bpy
    import mathutils
    import mathutils.kdtree
except ImportError as e:  # pragma: no cover
    print(f"import_check.py: bpy is not installed ({e}); scripts/install-bpy.sh", file=sys.stderr)
    sys.exit(3)


def main(argv):
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 3
    glb, dump_path = argv[0], argv[1]
    bake_light = "--bake-light" in argv[2:]
    with open(dump_path) as f:
        dump = json.load(f)
    sections = dump["sections"]
    by_kind = {}
    for s in sections:
        by_kind.setdefault(s["kind"], []).append(s)

    inst = by_kind.get("instances", [None])[0]
    records = inst["data"]["instances"] if inst else []
    models = inst["summary"]["models"] if inst else [s["name"][len("mesh:"):] for s in by_kind.get("mesh", [])]
    placed = {m: [r for r in records if r["model"] == m] for m in models}
    mesh_models = [m for m in models if placed[m] or not inst]
    has_terrain = "terrain" in by_kind
    want = {
        "meshes": len(mesh_models) + (1 if has_terrain else 0),
        "materials": len(by_kind.get("material", [])) + (1 if has_terrain else 0),
        "instances": len(records),
        "suns": len(by_kind.get("sun", [])),
    }

    bpy.ops.wm.read_factory_settings(use_empty=True)
    result = bpy.ops.import_scene.gltf(filepath=glb)
    if "FINISHED" not in result:
        print(f"import_check.py: the import returned {result}", file=sys.stderr)
        return 1

    meshes_used = {o.data.name for o in bpy.data.objects if o.type == "MESH"}
    got = {
        "meshes": len(meshes_used),
        "materials": len(bpy.data.materials),
        "instances": 0,
        "suns": sum(1 for o in bpy.data.objects if o.type == "LIGHT" and o.data.type == "SUN"),
    }
    failures = []
    meshes = {x["name"]: x for x in by_kind.get("mesh", [])}
    worst = {"vertex_m": 0.0, "origin_m": 0.0}
    for m in mesh_models:
        objs = [o for o in bpy.data.objects if o.type == "MESH" and o.data.name == m]
        if not inst:
            if not objs:
                failures.append(f"model {m}: no object uses its mesh")
            continue
        got["instances"] += len(objs)
        if len(objs) != len(placed[m]):
            failures.append(f"model {m}: {len(objs)} objects, the pack places {len(placed[m])}")
            continue
        section = next((x for x in meshes.values() if x["name"] == f"mesh:{m}"), None)
        if section is None or "positions" not in section.get("data", {}):
            failures.append(f"model {m}: the dump has no mesh:{m} positions (pass bake dump --full)")
            continue
        model_points = section["data"]["positions"]
        left = list(placed[m])
        for o in objs:
            world = [o.matrix_world @ v.co for v in o.data.vertices]
            tree = mathutils.kdtree.KDTree(len(world))
            for i, w in enumerate(world):
                tree.insert(w, i)
            tree.balance()
            origin = o.matrix_world.translation
            # The instance record nearest to the object's origin.
            k = min(range(len(left)), key=lambda i: (origin - mathutils.Vector(left[i]["position"])).length)
            r = left.pop(k)
            worst["origin_m"] = max(worst["origin_m"], (origin - mathutils.Vector(r["position"])).length)
            # docs/CONVENTIONS.md: world = position + R_z(rotation_deg) · (scale · p).
            c, s_ = math.cos(math.radians(r["rotation_deg"])), math.sin(math.radians(r["rotation_deg"]))
            ours = []
            for p in model_points:
                q = [r["scale"] * x for x in p]
                ours.append(mathutils.Vector((r["position"][0] + c * q[0] - s_ * q[1],
                                              r["position"][1] + s_ * q[0] + c * q[1],
                                              r["position"][2] + q[2])))
            mine = mathutils.kdtree.KDTree(len(ours))
            for i, w in enumerate(ours):
                mine.insert(w, i)
            mine.balance()
            # Every pack vertex on a Blender vertex and every Blender vertex on a pack vertex.
            d = max(max(tree.find(w)[2] for w in ours), max(mine.find(w)[2] for w in world))
            worst["vertex_m"] = max(worst["vertex_m"], d)
    for k, v in want.items():
        if got[k] != v:
            failures.append(f"{k}: Blender has {got[k]}, the pack gives {v}")
    if worst["vertex_m"] > 1e-3 or worst["origin_m"] > 1e-3:
        failures.append(f"instances off by {worst} (metres)")
    if bake_light:
        t = bpy.data.materials.get("terrain")
        images = []
        if t and t.use_nodes:
            images = [n.image.name for n in t.node_tree.nodes if n.type == "TEX_IMAGE" and n.image]
        if not any(" x " in i for i in images):
            failures.append(f"--bake-light: the terrain material reads {images}, not the baked image")
    print(json.dumps({"blender": bpy.app.version_string, "want": want, "got": got,
                      "worst_instance": worst, "failures": failures}))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
