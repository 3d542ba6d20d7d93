#!/usr/bin/env python3
"""The ground-truth harness: bake's renders against Mitsuba 3 path tracing of the same scene.

For each scene of scenes.toml (a pack built from its inputs) and each of its views:
  1. `bake mitsuba PACK -o DIR` writes the placed scene (src/mitsuba.rs); the harness checks the
     export's conventions: the `bakeschlick` plugin against `SchlickMaterial::eval` on the random
     directions of materials.json (within 1e-4), Mitsuba's envmap against the drawn sky in the
     directions of sky_probe.json;
  2. `bake render PACK -o T.exr --terms T` for T = all, direct, ambient (linear radiance) and
     `--regions` (per pixel the coverage of terrain, opaque model surfaces and leaves);
  3. Mitsuba renders scene.xml (all light, volpath) and direct.xml (the sun alone, max_depth 2);
     ambient = all − direct; the reference's regions are cast through the same camera with
     Mitsuba's ray queries (4×4 rays per pixel, masks passed where their opacity is below 0.5);
  4. per region (the reference's pixels of which the region covers at least half) and term: the
     mean ratio bake/reference of the luminance, and the relative RMS difference after a 5×5 box
     blur of both; the fraction of the reference's leaf coverage that bake draws; side-by-side
     images (bake | reference | error) as PNG;
     and, from a twin reference with another seed, the reference's own Monte Carlo noise
     beside each figure (the ratio's standard error, the RMS its noise alone adds);
  5. every figure is checked against bounds.toml: the issue's goal, or for a figure listed there
     as open, a regression guard around its measured value.

Also `conventions`: Mitsuba's directional and envmap emitters as the exporter writes them, over
a plane (albedo/π · E · cos θ under the sun alone, albedo · L under a uniform sky).

Usage: scripts/groundtruth/run.sh [ci|conventions] [--bench] [--out DIR] [--bake BIN]
                                    [--only SCENE] [--write-bounds] [--no-noise]
"""

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
TERMS = ("all", "direct", "ambient")
REGIONS = ("terrain", "opaque", "leaves", "sky")
# Region codes of the PLY attribute `region_x` (src/mitsuba.rs) and channels of bake's regions.
REGION_CODE = {"terrain": 1.0, "opaque": 2.0, "leaves": 3.0}
# A region's figures need this many of its pixels (fewer: reported, not checked).
MIN_PIXELS = 8

mi = None
dr = None


def load_mitsuba():
    global mi, dr
    import drjit
    import mitsuba

    mi, dr = mitsuba, drjit
    variant = "llvm_ad_rgb"
    try:
        mi.set_variant(variant)
    except Exception as e:  # no LLVM: the scalar variant is slower but the same
        print(f"groundtruth: {variant} unavailable ({e}); scalar_rgb", file=sys.stderr)
        variant = "scalar_rgb"
        mi.set_variant(variant)
    sys.path.insert(0, str(HERE))
    import bakeschlick

    bakeschlick.register()
    return variant


def luminance(img):
    return 0.2126 * img[..., 0] + 0.7152 * img[..., 1] + 0.0722 * img[..., 2]


def box5(a):
    """5×5 box blur with edge replication."""
    p = np.pad(a, 2, mode="edge")
    c = np.cumsum(np.cumsum(p, axis=0), axis=1)
    c = np.pad(c, ((1, 0), (1, 0)))
    h, w = a.shape
    return (c[5 : 5 + h, 5 : 5 + w] - c[:h, 5 : 5 + w] - c[5 : 5 + h, :w] + c[:h, :w]) / 25.0


def read_exr(path):
    return np.array(mi.Bitmap(str(path)), dtype=np.float64)[..., :3]


def write_png(path, rgb8):
    mi.Bitmap(np.ascontiguousarray(rgb8)).write(str(path))


def tone(img, s):
    """bake's display mapping: 1 − exp(−L·s), sRGB-encoded, 8 bits."""
    x = np.clip(1.0 - np.exp(-np.nan_to_num(img, posinf=1e6) * s), 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (x * 255.0 + 0.5).astype(np.uint8)


def run(cmd, **kw):
    t = time.time()
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    if r.returncode != 0:
        sys.exit(f"groundtruth: {' '.join(map(str, cmd))} failed ({r.returncode}):\n{r.stderr}")
    return r.stdout, time.time() - t


# ---------------------------------------------------------------------------------------------
# conventions


def conventions(out):
    """The emitters as src/mitsuba.rs writes them, over a plane; returns a list of results."""
    results = []
    albedo = 0.5

    def plane_scene(emitter):
        return {
            "type": "scene",
            "integrator": {"type": "volpath", "max_depth": 2},
            "sensor": {
                "type": "orthographic",
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]
                )
                @ mi.ScalarTransform4f().scale([0.5, 0.5, 1]),
                "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": 256},
            },
            "plane": {
                "type": "rectangle",
                "to_world": mi.ScalarTransform4f().scale([10, 10, 1]),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}},
            },
            "light": emitter,
        }

    # The sun alone: E = 3 from 30° elevation (direction of travel −s).
    elev = math.radians(30.0)
    s = [math.cos(elev) * math.cos(0.7), math.cos(elev) * math.sin(0.7), math.sin(elev)]
    e = 3.0
    img = np.array(
        mi.render(
            mi.load_dict(
                plane_scene(
                    {
                        "type": "directional",
                        "direction": [-s[0], -s[1], -s[2]],
                        "irradiance": {"type": "rgb", "value": e},
                    }
                )
            )
        )
    )
    want = albedo / math.pi * e * s[2]
    got = float(img.mean())
    results.append(("plane under the sun: albedo/π·E·cos θ", got, want, 1e-3))
    # A fully transparent mask card above the plane changes nothing at direct.xml's max_depth 2:
    # volpath passes masks without counting a bounce, on camera and on shadow rays.
    sc = plane_scene(
        {
            "type": "directional",
            "direction": [-s[0], -s[1], -s[2]],
            "irradiance": {"type": "rgb", "value": e},
        }
    )
    sc["card"] = {
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f().translate([0, 0, 1]).scale([10, 10, 1]),
        "bsdf": {"type": "mask", "opacity": {"type": "uniform", "value": 0.0}, "bsdf": {"type": "diffuse"}},
    }
    got = float(np.array(mi.render(mi.load_dict(sc))).mean())
    results.append(("the same under a transparent mask card (volpath, max_depth 2)", got, want, 1e-3))
    # A uniform sky of radiance L = 2 (a constant envmap image with the exporter's to_world).
    env = np.full((33, 64, 3), 2.0, dtype=np.float32)
    path = out / "conventions_sky.exr"
    mi.Bitmap(env).write(str(path))
    to_world = mi.ScalarTransform4f(
        [[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]]
    )
    img = np.array(
        mi.render(
            mi.load_dict(
                plane_scene({"type": "envmap", "filename": str(path), "to_world": to_world})
            ),
            spp=1024,
        )
    )
    got = float(img.mean())
    results.append(("plane under a uniform sky: albedo·L", got, albedo * 2.0, 1e-2))
    # The envmap's up axis and azimuth: a sky bright only near one world direction d (the
    # exporter's texel directions, src/mitsuba.rs `envmap_direction`), read back by eval.
    h, w = 65, 128
    d = np.array([math.cos(0.5) * math.cos(2.0), math.cos(0.5) * math.sin(2.0), math.sin(0.5)])
    env = np.zeros((h, w, 3), dtype=np.float32)
    for j in range(h):
        for i in range(w):
            if np.dot(envmap_direction(i, j, w, h), d) > math.cos(math.radians(8)):
                env[j, i] = 1.0
    mi.Bitmap(env).write(str(path))
    em = mi.load_dict({"type": "envmap", "filename": str(path), "to_world": to_world})
    toward = [d, -d, np.array([d[1], -d[0], d[2]]), np.array([d[0], d[1], -d[2]])]
    vals = [float(envmap_eval(em, np.array([v]))[0, 0]) for v in toward]
    results.append(("envmap: bright toward d", vals[0], 1.0, 1e-3))
    results.append(("envmap: dark away from d (−d, d turned 90°, d mirrored)", max(vals[1:]), 0.0, 1e-3))
    # The plugin's sampling against its own eval: for a leaf-like material (glossy wax over a
    # translucent diffuse layer), the mean sample weight f·cos/pdf equals ∫ f cos over the sphere
    # estimated with uniform directions (a wrong pdf shows as a bias).
    props = {"type": "bakeschlick", "translucence": 0.3}
    for side, layer in (
        ("top", dict(roughness=0.1, isotropy=1.0, diffuse=0.0, glossy=1.0, specular=0.0, color=[0.075] * 3)),
        ("bottom", dict(roughness=1.0, isotropy=1.0, diffuse=1.0, glossy=0.0, specular=0.0, color=[0.35, 0.6, 0.25])),
    ):
        for k, v in layer.items():
            props[f"{side}_{k}"] = {"type": "rgb", "value": v} if k == "color" else v
    bsdf = mi.load_dict(props)
    n = 1 << 18
    rng = np.random.default_rng(35)
    for theta in (0.3, 1.2):
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = vec3(np.tile([math.sin(theta), 0.0, math.cos(theta)], (n, 1)))
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        ctx = mi.BSDFContext()
        _, w = bsdf.sample(ctx, si, mi.Float(rng.random(n, dtype=np.float32)),
                           mi.Point2f(rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32)))
        sampled = float(np.array(w, dtype=np.float64).reshape(3, n)[1].mean())
        u = rng.normal(size=(n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        f = np.array(bsdf.eval(ctx, si, vec3(u)), dtype=np.float64).reshape(3, n)[1]
        uniform = float(f.mean() * 4 * math.pi)
        results.append((f"bakeschlick: sampled albedo = ∫ f cos at θ = {theta}", sampled, uniform, 0.01))
    ok = True
    for name, got, want, tol in results:
        good = abs(got - want) <= tol * max(1.0, abs(want))
        ok &= good
        print(f"  {'ok  ' if good else 'FAIL'} {name}: {got:.5f} (want {want:.5f} ± {tol:g})")
    return ok, [
        {"test": n, "value": g, "want": w, "tolerance": t} for n, g, w, t in results
    ]


def envmap_direction(i, j, w, h):
    """src/mitsuba.rs `envmap_direction`: Mitsuba's local direction of texel (i, j), in world."""
    theta = math.pi * j / (h - 1)
    phi = 2 * math.pi * (i + 0.5) / w
    local = (math.sin(theta) * math.sin(phi), math.cos(theta), -math.sin(theta) * math.cos(phi))
    return np.array([local[0], -local[2], local[1]])


def vec3(a):
    """An n × 3 array as a Dr.Jit vector (scalar variant: one lane at a time is not supported)."""
    a = np.asarray(a, dtype=np.float32)
    return mi.Vector3f(a[:, 0], a[:, 1], a[:, 2])


def envmap_eval(em, dirs):
    si = dr.zeros(mi.SurfaceInteraction3f, len(dirs))
    si.wi = vec3(-np.asarray(dirs))
    return np.array(em.eval(si), dtype=np.float64).reshape(3, len(dirs)).T


# ---------------------------------------------------------------------------------------------
# export checks


def check_export(mdir):
    """The plugin against bake's eval values, the envmap against bake's sky; returns figures."""
    import bakeschlick

    mats = json.loads((mdir / "materials.json").read_text())["materials"]
    worst = 0.0
    for m in mats:
        if m["kind"] != "bakeschlick":
            continue
        layer = lambda l: {
            **{k: mi.Float(l[k]) for k in bakeschlick.LAYER_KEYS},
            "color": mi.Color3f(*l["color"]),
        }
        top, bottom = layer(m["top"]), layer(m["bottom"])
        p = m["probes"]
        wi = np.array([x["wi"] for x in p], dtype=np.float32)
        wo = np.array([x["wo"] for x in p], dtype=np.float32)
        cm = np.array([x["map"] for x in p], dtype=np.float32)
        want = np.array([x["f"] for x in p])
        v = vec3
        got = np.array(
            bakeschlick.eval_schlick(
                top, bottom, mi.Float(m["translucence"]), v(wi), v(wo), mi.Color3f(v(cm))
            ),
            dtype=np.float64,
        ).reshape(3, -1).T
        # The plugin itself (eval = f·|cos θ_o|) through a BSDF built from the same parameters.
        props = {"type": "bakeschlick", "translucence": m["translucence"]}
        for side, l in (("top", m["top"]), ("bottom", m["bottom"])):
            for k in bakeschlick.LAYER_KEYS:
                props[f"{side}_{k}"] = l[k]
            props[f"{side}_color"] = {"type": "rgb", "value": l["color"]}
        worst_plugin = 0.0
        for key in {tuple(x) for x in cm.tolist()}:
            sel = np.all(cm == np.array(key, dtype=np.float32), axis=1)
            props["color_map"] = {"type": "rgb", "value": list(key)}
            bsdf = mi.load_dict(props)
            si = dr.zeros(mi.SurfaceInteraction3f, int(sel.sum()))
            si.wi = v(wi[sel])
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            f = np.array(bsdf.eval(mi.BSDFContext(), si, v(wo[sel])), dtype=np.float64)
            f = f.reshape(3, -1).T
            f = f / np.abs(wo[sel][:, 2:3])
            worst_plugin = max(worst_plugin, rel_err(f, want[sel]))
        worst = max(worst, rel_err(got, want), worst_plugin)
    probe = json.loads((mdir / "sky_probe.json").read_text())["probes"]
    scene = mi.load_file(str(mdir / "scene.xml"))
    em = next(e for e in scene.emitters() if e.is_environment())
    d = np.array([x["d"] for x in probe])
    want = np.array([x["radiance"] for x in probe])
    got = envmap_eval(em, d)
    sky_err = float(np.median(np.abs(luminance(got) - luminance(want)) / np.maximum(luminance(want), 1e-6)))
    return {"brdf_max_error": worst, "sky_median_error": sky_err}


def rel_err(got, want):
    return float(np.max(np.abs(got - want) / np.maximum(np.abs(want), 1.0)))


# ---------------------------------------------------------------------------------------------
# reference renders and regions


def reference_regions(scene, width, height, n=4):
    """Per pixel the coverage of terrain, opaque and leaves (H × W × 3) from n×n rays: the first
    surface each ray meets whose mask lets less than half of the light through."""
    sensor = scene.sensors()[0]
    ys, xs, a, b = np.meshgrid(np.arange(height), np.arange(width), np.arange(n), np.arange(n), indexing="ij")
    fx = ((xs + (b + 0.5) / n) / width).astype(np.float32).ravel()
    fy = ((ys + (a + 0.5) / n) / height).astype(np.float32).ravel()
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(fx, fy), mi.Point2f(0.5, 0.5))
    ray = mi.Ray3f(ray)
    region = dr.zeros(mi.Float, len(fx))
    active = dr.full(mi.Bool, True, len(fx))
    for _ in range(64):
        si = scene.ray_intersect(ray, active)
        hit = active & si.is_valid()
        nt = si.bsdf().eval_null_transmission(si, hit)
        through = hit & (nt[0] > 0.5)
        code = si.shape.eval_attribute_1("vertex_region", si, hit)
        region = dr.select(hit & ~through, code, region)
        active = through
        ray = mi.Ray3f(dr.select(through, si.spawn_ray(ray.d), ray))
        # One kernel per step, the same each time (cached), not one growing expression.
        dr.eval(region, active, ray)
        if not dr.any(active):
            break
    r = np.array(region).reshape(height, width, n * n)
    return np.stack([(np.abs(r - code) < 0.5).mean(axis=2) for code in REGION_CODE.values()], axis=2)


def render_reference(mdir, spp, seed=0, regions=True):
    out = {}
    t0 = time.time()
    for name, xml in (("all", "scene.xml"), ("direct", "direct.xml")):
        scene = mi.load_file(str(mdir / xml), spp=spp)
        out[name] = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)
        if name == "all" and regions:
            out["regions"] = reference_regions(
                scene, out[name].shape[1], out[name].shape[0]
            )
    out["ambient"] = out["all"] - out["direct"]
    out["seconds"] = time.time() - t0
    return out


# ---------------------------------------------------------------------------------------------
# metrics


def metrics(bake, ref, bake_regions, twin=None):
    """Figures per region and term, and the leaf fraction. `twin`: a second reference of the
    same scene with another seed; each figure then gets the reference's own Monte Carlo noise
    (`rms_noise`, `ratio_noise`, below)."""
    cov = ref["regions"]
    masks = {r: cov[..., c] >= 0.5 for c, r in enumerate(("terrain", "opaque", "leaves"))}
    masks["sky"] = cov.sum(axis=2) <= 0.5
    out = {"regions": {}, "pixels": {r: int(m.sum()) for r, m in masks.items()}}
    for region, mask in masks.items():
        out["regions"][region] = {}
        for term in TERMS:
            if region == "sky" and term != "all":
                continue  # bake draws the sky in every term, the reference only in `all`
            b, r = luminance(bake[term]), luminance(ref[term])
            m = mask & np.isfinite(b)
            if region == "sky":
                # Leave out the sun's disc (bake draws it, the reference's sun is a direction).
                med = np.median(r[m]) if m.any() else 0.0
                m &= (b < 20 * med + 1e-6) & (r < 20 * med + 1e-6)
            n = int(m.sum())
            if n < MIN_PIXELS:
                out["regions"][region][term] = {"pixels": n}
                continue
            bb, rb = box5(np.where(np.isfinite(b), b, 0.0)), box5(r)
            mean_r = float(r[m].mean())
            fig = {
                "pixels": n,
                "bake": float(b[m].mean()),
                "reference": mean_r,
                "ratio": float(b[m].mean() / mean_r) if mean_r > 0 else float("nan"),
                "rms": float(np.sqrt(np.mean((bb[m] - rb[m]) ** 2)) / max(float(rb[m].mean()), 1e-12)),
            }
            if twin is not None:
                # The reference's own noise, from its difference to the twin (independent
                # pixels, the same spp): per pixel var ≈ (r − r₂)²/2. rms_noise is the RMS the
                # reference's noise alone adds after the blur (relative, as `rms`; the measured
                # rms² ≈ bake's own error² + rms_noise²); ratio_noise is the standard error of
                # the region's mean ratio.
                dr = r - luminance(twin[term])
                noise_rms = np.sqrt(np.mean(box5(dr)[m] ** 2) / 2.0)
                fig["rms_noise"] = float(noise_rms / max(float(rb[m].mean()), 1e-12))
                se = np.sqrt(np.sum(dr[m] ** 2) / 2.0) / n
                fig["ratio_noise"] = float(fig["ratio"] * se / mean_r) if mean_r > 0 else float("nan")
            out["regions"][region][term] = fig
    # The reference's leaf pixels (leaves cover at least half) where bake draws a leaf (at
    # least one of its samples); the coverage-weighted overlap beside it, for information
    # (MSAA's four samples and the far cards' dither quantize bake's partial coverage).
    leaf_ref = cov[..., 2]
    leaf_px = leaf_ref >= 0.5
    out["leaf_fraction"] = (
        float((bake_regions[..., 2][leaf_px] > 0.0).mean()) if leaf_px.sum() >= MIN_PIXELS else None
    )
    out["leaf_overlap"] = (
        float(np.minimum(leaf_ref, bake_regions[..., 2]).sum() / leaf_ref.sum())
        if leaf_ref.sum() > 0
        else None
    )
    out["leaf_pixels_reference"] = float(leaf_ref.sum())
    out["leaf_pixels_bake"] = float(bake_regions[..., 2].sum())
    return out


def side_by_side(path, bake, ref):
    """bake | reference | error (red: bake brighter, blue: darker; full at ±50 % after the
    5×5 blur), tone-mapped with one exposure."""
    r = luminance(ref)
    mean = float(np.mean(r[np.isfinite(r)])) if np.isfinite(r).any() else 1.0
    s = math.log(2) / max(mean, 1e-6)
    bl, rl = box5(np.nan_to_num(luminance(bake), posinf=0.0)), box5(r)
    e = np.clip((bl - rl) / np.maximum(rl, 1e-6) / 0.5, -1, 1)
    err = np.stack([np.maximum(e, 0), np.zeros_like(e), np.maximum(-e, 0)], axis=2)
    err = (err * 255 + 0.5).astype(np.uint8)
    gap = np.full((bake.shape[0], 2, 3), 255, np.uint8)
    write_png(path, np.concatenate([tone(bake, s), gap, tone(ref, s), gap, err], axis=1))


# ---------------------------------------------------------------------------------------------
# bounds


def goal(bounds, term, what):
    g = bounds["goals"]
    if what == "ratio":
        t = g["ratio_tolerance"][term]
        return (1 - t, 1 + t)
    if what == "rms":
        return g["rms"].get(term)
    return g["leaf_fraction"]


def check_bounds(results, bounds):
    """Rows (key, value, bound, status); status PASS, OPEN (a guard holds), FAIL."""
    rows = []
    opened = bounds.get("open", {})
    for scene, views in results.items():
        for view, res in views.items():
            for region, terms in res["metrics"]["regions"].items():
                for term, fig in terms.items():
                    if "ratio" not in fig:
                        rows.append((f"{scene}.{view}.{region}.{term}", None, "too few pixels", "N/A"))
                        continue
                    for what in ("ratio", "rms"):
                        key = f"{scene}.{view}.{region}.{term}.{what}"
                        g = goal(bounds, term, what)
                        if g is None:
                            continue
                        v = fig[what]
                        meets = (g[0] <= v <= g[1]) if what == "ratio" else v <= g
                        if key in opened:
                            lo, hi = opened[key]
                            ok = lo <= v <= hi
                            status = ("PASS (goal met: tighten the bounds)" if meets else "OPEN") if ok else "FAIL"
                            rows.append((key, v, f"guard [{lo:.3f}, {hi:.3f}], goal {fmt_goal(g)}", status))
                        else:
                            rows.append((key, v, f"goal {fmt_goal(g)}", "PASS" if meets else "FAIL"))
            key = f"{scene}.{view}.leaf_fraction"
            v = res["metrics"]["leaf_fraction"]
            if v is None:
                rows.append((key, None, f"fewer than {MIN_PIXELS} leaf pixels in the reference", "N/A"))
                continue
            g = goal(bounds, None, "leaf")
            meets = v >= g
            if key in opened:
                lo, hi = opened[key]
                ok = lo <= v <= hi
                status = ("PASS (goal met: tighten the bounds)" if meets else "OPEN") if ok else "FAIL"
                rows.append((key, v, f"guard [{lo:.3f}, {hi:.3f}], goal ≥ {g}", status))
            else:
                rows.append((key, v, f"goal ≥ {g}", "PASS" if meets else "FAIL"))
    return rows


def fmt_goal(g):
    return f"[{g[0]:.2f}, {g[1]:.2f}]" if isinstance(g, tuple) else f"≤ {g}"


def guard_bounds(results, bounds, margin_ratio, margin_rms):
    """The open guards of every figure that misses its goal now: the goal's range widened to
    the measured value plus a margin (fails on a regression, passes on an improvement)."""
    guards = {}
    for key, v, _, status in check_bounds(results, {**bounds, "open": {}}):
        if status != "FAIL":
            continue
        if key.endswith(".ratio"):
            term = key.split(".")[-2]
            lo, hi = goal(bounds, term, "ratio")
            guards[key] = [round(min(lo, v - margin_ratio), 3), round(max(hi, v + margin_ratio), 3)]
        elif key.endswith(".rms"):
            guards[key] = [0.0, round(v * (1 + margin_rms) + 0.01, 3)]
        else:
            guards[key] = [round(max(0.0, v - margin_ratio), 3), 1.0]
    return guards


# ---------------------------------------------------------------------------------------------
# scenes


def build_scene(cfg, bake, work):
    """Runs the scene's commands ({bake}, {work}, {root}, {pack} substituted); returns the pack."""
    pack = work / f"{cfg['name']}.bake"
    subst = {"bake": str(bake), "work": str(work), "root": str(ROOT), "pack": str(pack)}
    for cmd in cfg["build"]:
        if cmd[0] == "copy":  # ["copy", SRC..., DSTDIR]
            dst = Path(cmd[-1].format(**subst))
            dst.mkdir(parents=True, exist_ok=True)
            for src in cmd[1:-1]:
                shutil.copy(src.format(**subst), dst)
            continue
        run([c.format(**subst) for c in cmd], cwd=ROOT)
    return pack


def view_args(view, width, height):
    a = ["--width", width, "--height", height]
    for k in ("eye", "target"):
        if k in view:
            a += [f"--{k}", ",".join(str(x) for x in view[k])]
    if "fov" in view:
        a += ["--fov", view["fov"]]
    return a


def run_view(bake, pack, scene_name, view, settings, out, noise=True):
    vdir = out / scene_name / view["name"]
    mdir = vdir / "mitsuba"
    vdir.mkdir(parents=True, exist_ok=True)
    w, h = settings["width"], settings["height"]
    va = view_args(view, w, h)
    exp, _ = run([bake, "mitsuba", pack, "-o", mdir, "--json", "--quiet", *va])
    timing = {}
    t = time.time()
    for term in TERMS:
        extra = ["--regions", vdir / "bake_regions.exr"] if term == "all" else []
        run([bake, "render", pack, "-o", vdir / f"bake_{term}.exr", "--terms", term, "--quiet", *va, *extra])
    timing["bake_render"] = time.time() - t
    bake_img = {t: read_exr(vdir / f"bake_{t}.exr") for t in TERMS}
    bake_regions = read_exr(vdir / "bake_regions.exr")
    checks = check_export(mdir)
    ref = render_reference(mdir, settings["spp"])
    timing["reference"] = ref["seconds"]
    # Its twin with another seed: the reference's own noise beside each figure.
    twin = render_reference(mdir, settings["spp"], seed=1, regions=False) if noise else None
    if twin is not None:
        timing["reference_twin"] = twin["seconds"]
    for t in ("all", "direct", "ambient"):
        mi.Bitmap(ref[t].astype(np.float32)).write(str(vdir / f"reference_{t}.exr"))
        side_by_side(vdir / f"side_{t}.png", bake_img[t], ref[t])
    reg = lambda c: (np.clip(c, 0, 1) * 255 + 0.5).astype(np.uint8)
    gap = np.full((h, 2, 3), 255, np.uint8)
    write_png(vdir / "regions.png", np.concatenate([reg(bake_regions), gap, reg(ref["regions"])], axis=1))
    m = metrics(bake_img, ref, bake_regions, twin)
    return {"export": json.loads(exp), "checks": checks, "metrics": m, "seconds": timing}


def table(results):
    lines = []
    for scene, views in results.items():
        for view, res in views.items():
            m = res["metrics"]
            lf = m["leaf_fraction"]
            lines.append(
                f"\n{scene} / {view}: leaf pixels drawn {('%.3f' % lf) if lf is not None else 'n/a'}"
                f" (coverage overlap {('%.3f' % m['leaf_overlap']) if m['leaf_overlap'] is not None else 'n/a'};"
                f" leaf coverage: reference {m['leaf_pixels_reference']:.1f} px, bake {m['leaf_pixels_bake']:.1f} px);"
                f" BRDF check max error {res['checks']['brdf_max_error']:.2e},"
                f" sky probe median error {res['checks']['sky_median_error']:.2e}"
            )
            lines.append("| region | pixels | all ratio | all RMS | direct ratio | direct RMS | ambient ratio | ambient RMS |")
            lines.append("|---|---|---|---|---|---|---|---|")
            for region in REGIONS:
                terms = m["regions"][region]
                cells = []
                for term in TERMS:
                    f = terms.get(term)
                    if f is None or "ratio" not in f:
                        cells += ["–", "–"]
                    elif "rms_noise" in f:
                        # The reference's own noise beside each figure: ± the ratio's standard
                        # error, (the RMS its noise alone adds).
                        cells += [f"{f['ratio']:.3f} ±{f['ratio_noise']:.3f}", f"{f['rms']:.3f} ({f['rms_noise']:.3f})"]
                    else:
                        cells += [f"{f['ratio']:.3f}", f"{f['rms']:.3f}"]
                lines.append(f"| {region} | {m['pixels'][region]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("command", nargs="?", default="ci", choices=["ci", "conventions"])
    ap.add_argument("--bake", default=os.environ.get("BAKE", str(ROOT / "target/debug/bake")))
    ap.add_argument("--out", default=str(ROOT / "out/groundtruth"))
    ap.add_argument("--scenes", default=str(HERE / "scenes.toml"))
    ap.add_argument("--bounds", default=str(HERE / "bounds.toml"))
    ap.add_argument("--bench", action="store_true", help="the larger views of scenes.toml [bench]")
    ap.add_argument("--only", action="append", help="scene names to run (default: all)")
    ap.add_argument("--no-noise", action="store_true",
                    help="skip the reference's twin (another seed) that measures its own noise")
    ap.add_argument("--write-bounds", action="store_true",
                    help="print the open guards of the figures that miss their goals now (TOML)")
    args = ap.parse_args()
    t0 = time.time()
    variant = load_mitsuba()
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    print(f"groundtruth: Mitsuba {mi.__version__} ({variant}), output in {out}")
    print("== conventions")
    ok, conv = conventions(out)
    if args.command == "conventions":
        sys.exit(0 if ok else 1)
    cfg = tomllib.loads(Path(args.scenes).read_text())
    bounds = tomllib.loads(Path(args.bounds).read_text())
    settings = cfg["bench"] if args.bench else cfg["settings"]
    bake = Path(args.bake).resolve()
    results = {}
    for sc in cfg["scene"]:
        if args.only and sc["name"] not in args.only:
            continue
        print(f"== {sc['name']}")
        t = time.time()
        pack = build_scene(sc, bake, out)
        print(f"  pack built in {time.time() - t:.1f} s")
        results[sc["name"]] = {}
        for view in sc["view"]:
            t = time.time()
            res = run_view(bake, pack, sc["name"], view, settings, out, noise=not args.no_noise)
            results[sc["name"]][view["name"]] = res
            c = res["checks"]
            print(f"  {view['name']}: {time.time() - t:.1f} s (reference {res['seconds']['reference']:.1f} s);"
                  f" BRDF check {c['brdf_max_error']:.1e}, sky probe {c['sky_median_error']:.1e}")
            ok &= c["brdf_max_error"] <= bounds["goals"]["brdf_check"]
            ok &= c["sky_median_error"] <= bounds["goals"]["sky_probe"]
    print(table(results))
    rows = check_bounds(results, bounds)
    print("\n== bounds (scripts/groundtruth/bounds.toml)")
    for key, v, bound, status in rows:
        vs = "–" if v is None else f"{v:.3f}"
        print(f"  {status:<5} {key} = {vs} ({bound})")
    fails = [r for r in rows if r[3] == "FAIL"]
    ok &= not fails
    report = {
        "mitsuba": mi.__version__, "variant": variant, "bench": args.bench, "settings": settings,
        "conventions": conv, "results": results,
        "bounds": [{"key": k, "value": v, "bound": b, "status": s} for k, v, b, s in rows],
        "seconds": time.time() - t0,
    }
    (out / "report.json").write_text(json.dumps(report, indent=1))
    (out / "table.md").write_text(table(results) + "\n")
    if args.write_bounds:
        print("\n# open guards (measured ± margin):")
        for k, v in sorted(guard_bounds(results, bounds, bounds["guard_margin"]["ratio"],
                                        bounds["guard_margin"]["rms"]).items()):
            print(f'"{k}" = [{v[0]}, {v[1]}]')
    print(f"\ngroundtruth: {'ok' if ok else 'FAILED'} in {time.time() - t0:.1f} s"
          f" ({len(fails)} figures out of bounds)")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
