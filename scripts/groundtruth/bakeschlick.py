"""bake's two-layer Schlick BRDF as a Mitsuba 3 BSDF plugin (`bakeschlick`).

The formulas of docs/MATERIALS.md and src/material/schlick.rs `SchlickMaterial::eval`, directions in
the shading frame (n = +Z, tangent = +X):

    layer:  C·a/π + S(u)·[b·G(v)G(v')·Z(t)·A(w)/(4π v v')]   (the specular δ term c is not drawn)
            S(u) = C + (1 − C)(1 − u)^5 (S ≡ 0 where C = 0 in every channel: no interface),
            Z(t) = r/(1 + r t² − t²)², A(w) = sqrt(p/(p² − p² w² + w²)),
            G(v) = 2v/(v + sqrt(r + (1 − r) v²))
    stack:  f = (1 − τ)·[f_top + (1 − S_top(v'))(1 − S_top(v))·f_bottom]   (same side, two-sided)
            f = τ·C_bottom·map/π                                        (opposite sides)

u = wo·h with h the half vector of the directions mirrored to the upper side, t = h_z, w = h_x/|h_xy|.
Sampling: cosine-weighted, on the other side with probability τ (0.5 at most), else on wi's side.
`eval_schlick` is the same function on plain arrays: `check_brdf` compares it (and the plugin's own
`eval`) with bake's values in materials.json.
"""

import drjit as dr
import mitsuba as mi

LAYER_KEYS = ("roughness", "isotropy", "diffuse", "glossy", "specular")


def _fresnel(color, u):
    m = 1.0 - dr.clip(u, 0.0, 1.0)
    m2 = m * m
    none = (color.x == 0.0) & (color.y == 0.0) & (color.z == 0.0)
    return dr.select(none, 0.0, color + (1.0 - color) * (m2 * m2 * m))


def _shadowing(r, v):
    r = dr.maximum(r, 1e-4)
    return 2.0 * v / (v + dr.sqrt(r + (1.0 - r) * v * v))


def _glossy_lobe(layer, wi, wo, h):
    v, vp = wo.z, wi.z
    r = dr.maximum(layer["roughness"], 1e-4)
    t = h.z
    z = r / dr.square(1.0 + r * t * t - t * t)
    p = dr.clip(layer["isotropy"], 1e-4, 1.0)
    hxy = dr.sqrt(h.x * h.x + h.y * h.y)
    w = dr.select(hxy > 1e-7, h.x / dr.maximum(hxy, 1e-30), 1.0)
    a = dr.sqrt(p / (p * p - p * p * w * w + w * w))
    return _shadowing(r, v) * _shadowing(r, vp) * z * a / (4.0 * dr.pi * v * vp)


def _reflectance(layer, color, wi, wo, h, u):
    g = layer["glossy"] * _glossy_lobe(layer, wi, wo, h)
    return color * (layer["diffuse"] / dr.pi) + _fresnel(color, u) * g


def eval_schlick(top, bottom, translucence, wi, wo, cmap):
    """f(wi, wo) (no cosine) for layer dicts (`LAYER_KEYS` floats, `color` a mi.Color3f), vectors
    in the shading frame and the colour map value `cmap` (mi.Color3f)."""
    bottom_color = bottom["color"] * cmap
    same = (wi.z > 0.0) == (wo.z > 0.0)
    valid = (wi.z != 0.0) & (wo.z != 0.0)
    wi_u = mi.Vector3f(wi.x, wi.y, dr.abs(wi.z))
    wo_u = mi.Vector3f(wo.x, wo.y, dr.abs(wo.z))
    h = dr.normalize(wi_u + wo_u)
    u = dr.clip(dr.dot(wo_u, h), 0.0, 1.0)
    rt = _reflectance(top, top["color"], wi_u, wo_u, h, u)
    rb = _reflectance(bottom, bottom_color, wi_u, wo_u, h, u)
    through = (1.0 - _fresnel(top["color"], wi_u.z)) * (1.0 - _fresnel(top["color"], wo_u.z))
    f_same = (1.0 - translucence) * (rt + through * rb)
    f_other = translucence * bottom_color / dr.pi
    f = dr.select(same, f_same, f_other)
    return dr.select(valid, f, 0.0)


class BakeSchlick(mi.BSDF):
    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.layers = []
        for side in ("top", "bottom"):
            layer = {k: mi.Float(props.get(f"{side}_{k}", 0.0)) for k in LAYER_KEYS}
            c = props.get(f"{side}_color", None)
            layer["color"] = mi.Color3f(c) if c is not None else mi.Color3f(0.0)
            self.layers.append(layer)
        self.translucence = mi.Float(props.get("translucence", 0.0))
        # A texture, or a constant colour (the BRDF check's probes).
        self.color_map = props.get("color_map", None)
        if self.color_map is not None and not isinstance(self.color_map, mi.Texture):
            self.color_map = mi.Color3f(self.color_map)
        tau = float(props.get("translucence", 0.0))
        self.p_other = min(tau, 0.5) if tau > 0.0 else 0.0
        flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        self.m_components = [flags]
        if self.p_other > 0.0:
            t = mi.BSDFFlags.DiffuseTransmission | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            self.m_components.append(t)
            flags = flags | t
        self.m_flags = flags

    def _map(self, si, active):
        if self.color_map is None:
            return mi.Color3f(1.0)
        if isinstance(self.color_map, mi.Texture):
            return self.color_map.eval(si, active)
        return self.color_map

    def _f(self, si, wo, active):
        return eval_schlick(
            self.layers[0], self.layers[1], self.translucence, si.wi, wo, self._map(si, active)
        )

    def _pdf(self, si, wo):
        same = (si.wi.z > 0.0) == (wo.z > 0.0)
        side = dr.select(same, 1.0 - self.p_other, self.p_other)
        return side * dr.abs(wo.z) * dr.inv_pi

    def sample(self, ctx, si, sample1, sample2, active=True):
        local = mi.warp.square_to_cosine_hemisphere(sample2)
        other = sample1 < self.p_other
        up = (si.wi.z >= 0.0) != other
        wo = mi.Vector3f(local.x, local.y, dr.select(up, local.z, -local.z))
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = wo
        bs.pdf = self._pdf(si, wo)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(
            dr.select(other, +mi.BSDFFlags.DiffuseTransmission, +mi.BSDFFlags.DiffuseReflection)
        )
        bs.sampled_component = dr.select(other, mi.UInt32(1), mi.UInt32(0))
        f = self._f(si, wo, active) * dr.abs(wo.z)
        ok = active & (bs.pdf > 0.0)
        return bs, dr.select(ok, f / dr.maximum(bs.pdf, 1e-30), 0.0)

    def eval(self, ctx, si, wo, active=True):
        return dr.select(active, self._f(si, wo, active) * dr.abs(wo.z), 0.0)

    def pdf(self, ctx, si, wo, active=True):
        return dr.select(active, self._pdf(si, wo), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def traverse(self, callback):
        pass

    def to_string(self):
        return "BakeSchlick[]"


def register():
    mi.register_bsdf("bakeschlick", lambda props: BakeSchlick(props))
