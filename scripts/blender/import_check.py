#!/usr/bin/env python3
"""Blender (PyPI `bpy`, pinned in scripts/blender/requirements.txt) imports `bake export`'s GLB;
the counts and the instances are checked against `bake dump --json --full` of the same pack.

    python scripts/blender/import_check.py SCENE.glb DUMP.json [--bake-light] [--lod]
        [--vertex-ambient] [--normal-maps]

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
- with --bake-light: the terrain material's base colour reads the `<colour> x <light map>` image;
- images: one per colour map the materials name, plus the terrain's (its colour map, or the
  `--bake-light` image), plus with --normal-maps one per normal map;
- with --lod (the export's `MSFT_lod`): Blender's importer (4.5) does not read `MSFT_lod`; it
  imports the level nodes, which are in no scene, into a collection "Orphan Nodes", outside the
  root node that turns glTF's Y-up into bake's Z-up. So per model with a `lod` section that has
  levels past the full mesh (or a skeleton), one Blender mesh `<model> lod<l>` per level with
  the section's triangle count and `<model> skeleton` with its segments as edges and
  2·segments + points vertices, each used by as many objects as the pack places, all in
  "Orphan Nodes", each object's origin at an instance's position p seen in glTF's frame,
  Blender (p.x, −p.z, p.y): every level is drawn too, lying on its side (docs/MATERIALS.md).
  The skeleton's material counts among the materials;
- with --vertex-ambient: each placed model with a `prt` section, and its levels, has one colour
  attribute, whose every corner colour (8-bit sRGB in Blender) is one of the GLB's COLOR_0
  values of that mesh within 1.5/255, and each of its materials multiplies a colour-attribute
  node into the base colour; the other meshes have none;
- with --normal-maps: each material whose section names a `normal_map` has a normal-map node,
  fed by a non-colour image, driving the BSDF's normal; no other material has one.
Prints a JSON summary; exit 0 when all hold, 1 otherwise, 3 when bpy cannot run.
"""
import json
import math
import struct
import sys

try:
    import bpy
    import mathutils
    import mathutils.kdtree
except ImportError as e:  # pragma: no cover
    print(f"import_check.py: bpy is not installed ({e}); scripts/install-bpy.sh", file=sys.stderr)
    sys.exit(3)


def glb_colors(glb):
    """Per glTF mesh name, the COLOR_0 values (linear RGB) of its primitives."""
    with open(glb, "rb") as f:
        data = f.read()
    json_len = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + json_len])
    bin_at = 20 + json_len
    blob = data[bin_at + 8:bin_at + 8 + struct.unpack_from("<I", data, bin_at)[0]]
    out = {}
    for mesh in doc.get("meshes", []):
        values = out.setdefault(mesh.get("name"), [])
        for prim in mesh["primitives"]:
            a = prim["attributes"].get("COLOR_0")
            if a is None:
                continue
            acc = doc["accessors"][a]
            view = doc["bufferViews"][acc["bufferView"]]
            n = {"VEC3": 3, "VEC4": 4}[acc["type"]]
            assert acc["componentType"] == 5126, "float COLOR_0"
            start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
            flat = struct.unpack_from(f"<{acc['count'] * n}f", blob, start)
            values.extend(flat[i:i + 3] for i in range(0, len(flat), n))
    return out


def srgb(c):
    return 12.92 * c if c <= 0.0031308 else 1.055 * c ** (1 / 2.4) - 0.055


def feeds(link_target, node_type, nodes_seen=None):
    """Whether a node of `node_type` reaches socket `link_target` through the node tree."""
    seen = nodes_seen or set()
    for link in link_target.links:
        n = link.from_node
        if n.type == node_type:
            return True
        if n.name in seen:
            continue
        seen.add(n.name)
        if any(feeds(i, node_type, seen) for i in n.inputs if i.is_linked):
            return True
    return False


def main(argv):
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 3
    glb, dump_path = argv[0], argv[1]
    bake_light = "--bake-light" in argv[2:]
    lod = "--lod" in argv[2:]
    vertex_ambient = "--vertex-ambient" in argv[2:]
    normal_maps = "--normal-maps" in argv[2:]
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
    materials = by_kind.get("material", [])
    # The levels the export writes with --lod: per placed model, levels 1.. and the skeleton.
    lods = {x["summary"]["mesh_section"][len("mesh:"):]: x["summary"] for x in by_kind.get("lod", [])}
    levels = {}  # Blender mesh name -> (model, {"triangles": n} or {"skeleton": summary})
    if lod:
        for m in mesh_models:
            summary = lods.get(m)
            if not summary or not placed[m]:
                continue
            for i, level in enumerate(summary["levels"][1:], start=1):
                levels[f"{m} lod{i}"] = (m, {"triangles": level["triangles"]})
            if summary.get("skeleton"):
                levels[f"{m} skeleton"] = (m, {"skeleton": summary["skeleton"]})
    skeletons = sum(1 for _, what in levels.values() if "skeleton" in what)
    prt_models = {x["summary"]["mesh"][len("mesh:"):] for x in by_kind.get("prt", [])}
    colored = [m for m in mesh_models if m in prt_models and placed[m]] if vertex_ambient else []
    colored_meshes = colored + [name for name, (m, what) in levels.items() if m in colored and "triangles" in what]
    used_materials = [x for x in materials if x["summary"]["mesh"][len("mesh:"):] in mesh_models]
    images = {x["summary"]["color_map"] for x in used_materials if x["summary"].get("color_map")}
    if normal_maps:
        images |= {x["summary"]["normal_map"] + " normal" for x in used_materials if x["summary"].get("normal_map")}
    want = {
        "meshes": len(mesh_models) + (1 if has_terrain else 0) + len(levels),
        "materials": len(materials) + (1 if has_terrain else 0) + skeletons,
        "instances": len(records),
        "suns": len(by_kind.get("sun", [])),
        "images": len(images) + (1 if has_terrain else 0),
        "level_meshes": len(levels),
        "level_instances": sum(len(placed[m]) for m, _ in levels.values()),
        "color_attributes": len(colored_meshes),
        "normal_maps": sum(1 for x in used_materials if x["summary"].get("normal_map")) if normal_maps else 0,
    }

    bpy.ops.wm.read_factory_settings(use_empty=True)
    result = bpy.ops.import_scene.gltf(filepath=glb)
    if "FINISHED" not in result:
        print(f"import_check.py: the import returned {result}", file=sys.stderr)
        return 1

    def orphan(o):
        return any(c.name.startswith("Orphan Nodes") for c in o.users_collection)

    meshes_used = {o.data.name for o in bpy.data.objects if o.type == "MESH"}
    bsdf_normal = [
        m.name for m in bpy.data.materials if m.use_nodes and any(
            n.type == "BSDF_PRINCIPLED" and feeds(n.inputs["Normal"], "NORMAL_MAP") for n in m.node_tree.nodes)
    ]
    got = {
        "meshes": len(meshes_used),
        "materials": len(bpy.data.materials),
        "instances": 0,
        "suns": sum(1 for o in bpy.data.objects if o.type == "LIGHT" and o.data.type == "SUN"),
        "images": len(bpy.data.images),
        "level_meshes": 0,
        "level_instances": 0,
        "color_attributes": sum(1 for me in bpy.data.meshes if me.users and len(me.color_attributes)),
        "normal_maps": len(bsdf_normal),
    }
    failures = []
    meshes = {x["name"]: x for x in by_kind.get("mesh", [])}
    worst = {"vertex_m": 0.0, "origin_m": 0.0, "level_origin_m": 0.0, "color_srgb": 0.0}
    # --lod: the level meshes, their objects in "Orphan Nodes", placed in glTF's frame.
    for name, (m, what) in levels.items():
        objs = [o for o in bpy.data.objects if o.type == "MESH" and o.data.name == name]
        if not objs:
            failures.append(f"--lod: no object uses the level mesh {name!r}")
            continue
        got["level_meshes"] += 1
        got["level_instances"] += len(objs)
        me = objs[0].data
        if "triangles" in what and len(me.polygons) != what["triangles"]:
            failures.append(f"--lod: {name} has {len(me.polygons)} faces, the pack's level {what['triangles']} triangles")
        if "skeleton" in what:
            sk = what["skeleton"]
            if len(me.edges) != sk["segments"] or len(me.vertices) != 2 * sk["segments"] + sk["points"]:
                failures.append(f"--lod: {name} has {len(me.edges)} edges and {len(me.vertices)} vertices, "
                                f"the pack's skeleton {sk['segments']} segments and {sk['points']} points")
        if not all(orphan(o) for o in objs):
            failures.append(f"--lod: {name}'s objects are not all in Orphan Nodes")
        left = [mathutils.Vector((r["position"][0], -r["position"][2], r["position"][1])) for r in placed[m]]
        for o in objs:
            origin = o.matrix_world.translation
            k = min(range(len(left)), key=lambda i: (origin - left[i]).length) if left else None
            if k is None:
                failures.append(f"--lod: {name} has more objects than the pack places")
                break
            worst["level_origin_m"] = max(worst["level_origin_m"], (origin - left.pop(k)).length)
    # --vertex-ambient: the colour attributes against the GLB's COLOR_0, and the material nodes.
    if vertex_ambient:
        values = glb_colors(glb)
        for name in colored_meshes:
            me = bpy.data.meshes.get(name)
            if me is None or len(me.color_attributes) != 1:
                failures.append(f"--vertex-ambient: mesh {name!r} has no single colour attribute")
                continue
            ref = values.get(name) or []
            if not ref:
                failures.append(f"--vertex-ambient: the GLB's mesh {name!r} has no COLOR_0")
                continue
            tree = mathutils.kdtree.KDTree(len(ref))
            for i, c in enumerate(ref):
                tree.insert([srgb(x) for x in c], i)
            tree.balance()
            attr = me.color_attributes[0]
            for d in attr.data:
                worst["color_srgb"] = max(worst["color_srgb"], tree.find(list(d.color_srgb)[:3])[2])
            for mat in me.materials:
                ok = mat and mat.use_nodes and any(
                    n.type == "BSDF_PRINCIPLED" and feeds(n.inputs["Base Color"], "VERTEX_COLOR")
                    for n in mat.node_tree.nodes)
                if not ok:
                    failures.append(f"--vertex-ambient: material {mat and mat.name!r} of {name!r} does not multiply the colour attribute into the base colour")
        if worst["color_srgb"] > 1.5 / 255:
            failures.append(f"--vertex-ambient: a colour attribute is {worst['color_srgb'] * 255:.2f}/255 from every COLOR_0 value")
    # --normal-maps: the materials with a normal map node, and its image read as data.
    if normal_maps:
        names = {x["summary"]["name"] for x in used_materials if x["summary"].get("normal_map")}
        if set(bsdf_normal) != names:
            failures.append(f"--normal-maps: normal-map nodes on {sorted(bsdf_normal)}, the pack's normal maps on {sorted(names)}")
        for mname in bsdf_normal:
            for n in bpy.data.materials[mname].node_tree.nodes:
                if n.type == "NORMAL_MAP":
                    img = [lk.from_node.image for lk in n.inputs["Color"].links if lk.from_node.type == "TEX_IMAGE"]
                    if not img or img[0].colorspace_settings.name != "Non-Color":
                        failures.append(f"--normal-maps: {mname}'s normal map does not read a non-colour image")
    for m in mesh_models:
        objs = [o for o in bpy.data.objects if o.type == "MESH" and o.data.name == m and not orphan(o)]
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
    if worst["vertex_m"] > 1e-3 or worst["origin_m"] > 1e-3 or worst["level_origin_m"] > 1e-3:
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
