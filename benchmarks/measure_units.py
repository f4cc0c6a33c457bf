"""Measure Cycles light conventions against analytic formulas (docs/radiometry.md).

Run:  .venv/bin/python -m benchmarks.measure_units [name-substring ...]
Each case renders a direct-light-only Cycles image of a Lambertian plane
(albedo 0.8, z = 0) seen by an orthographic camera looking straight down, and
compares it per pixel with an irradiance E computed in numpy: radiance = rho E / pi.
Printed: ratio = sum(measured)/sum(predicted), relMSE and the max relative
error over pixels brighter than 5% of the peak.
"""
import math
import sys

import bpy
import numpy as np

from benchmarks import metrics, reference
from benchmarks.scenes import light as add_light

RHO = 0.8
RES = 32


# ---------------------------------------------------------------- scene helpers
def new_scene():
    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene


def mesh_object(scene, name, verts, faces, material=None, loc=(0, 0, 0)):
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.update()
    if material is not None:
        me.materials.append(material)
    ob = bpy.data.objects.new(name, me)
    ob.location = loc
    scene.collection.objects.link(ob)
    return ob


def diffuse_material(albedo=RHO, kind="DIFFUSE"):
    m = bpy.data.materials.new("plane_" + kind)
    nt = m.node_tree
    p = nt.nodes["Principled BSDF"]
    out = nt.nodes["Material Output"]
    if kind == "DIFFUSE":
        d = nt.nodes.new("ShaderNodeBsdfDiffuse")
        d.inputs["Color"].default_value = (albedo, albedo, albedo, 1)
        d.inputs["Roughness"].default_value = 0.0
        nt.links.new(d.outputs[0], out.inputs["Surface"])
    else:
        p.inputs["Base Color"].default_value = (albedo, albedo, albedo, 1)
        if kind in ("PRINCIPLED_R1", "PRINCIPLED_R1_NOSPEC"):
            p.inputs["Roughness"].default_value = 1.0
        if kind == "PRINCIPLED_R1_NOSPEC":
            p.inputs["Specular IOR Level"].default_value = 0.0
    return m


def emission_material(color, strength, principled=False):
    m = bpy.data.materials.new("emit")
    nt = m.node_tree
    if principled:
        p = nt.nodes["Principled BSDF"]
        p.inputs["Base Color"].default_value = (0, 0, 0, 1)
        p.inputs["Specular IOR Level"].default_value = 0.0
        p.inputs["Emission Color"].default_value = (*color, 1)
        p.inputs["Emission Strength"].default_value = strength
    else:
        e = nt.nodes.new("ShaderNodeEmission")
        e.inputs["Color"].default_value = (*color, 1)
        e.inputs["Strength"].default_value = strength
        nt.links.new(e.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    return m


def quad(scene, name, sx, sy, z, material, flip=False):
    v = [(-sx / 2, -sy / 2, 0), (sx / 2, -sy / 2, 0), (sx / 2, sy / 2, 0), (-sx / 2, sy / 2, 0)]
    f = [(0, 3, 2, 1)] if flip else [(0, 1, 2, 3)]  # CCW from +z = normal +z
    return mesh_object(scene, name, v, f, material, loc=(0, 0, z))


def setup(extent, plane_kind="DIFFUSE", plane_size=400.0, cam_z=30.0):
    scene = new_scene()
    quad(scene, "plane", plane_size, plane_size, 0.0, diffuse_material(RHO, plane_kind))
    cam = bpy.data.cameras.new("cam")
    cam.type = "ORTHO"
    cam.ortho_scale = extent
    cam.clip_end = 1000
    co = bpy.data.objects.new("cam", cam)
    co.location = (0, 0, cam_z)  # identity rotation: looks down -z, image up = +y
    scene.collection.objects.link(co)
    scene.camera = co
    scene.render.resolution_x = scene.render.resolution_y = RES
    w = bpy.data.worlds.new("black")
    w.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = w
    scene["extent"] = extent
    return scene


def pixel_points(extent):
    """World (x, y) of pixel centres, row 0 = top = +y."""
    c = (np.arange(RES) + 0.5) / RES * extent - extent / 2
    x, y = np.meshgrid(c, -c)
    return x, y


def radiance(E):
    return np.repeat((RHO / math.pi * E)[..., None], 3, axis=2)


# ------------------------------------------------------------ analytic models
def smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def spot_att(v, size, blend):
    """v: unit vectors light -> receiver in the light frame (axis = -z)."""
    ch = math.cos(size / 2)
    if blend <= 0:
        return (-v[..., 2] > ch).astype(float)
    return smoothstep((-v[..., 2] - ch) / ((1 - ch) * blend))


def E_point(extent, P, h, size=None, blend=0.0):
    x, y = pixel_points(extent)
    d = np.stack([x, y, -h * np.ones_like(x)], -1)  # light -> receiver
    t = np.linalg.norm(d, axis=-1)
    v = d / t[..., None]
    att = 1.0 if size is None else spot_att(v, size, blend)
    return P / (4 * math.pi) * att * (h / t) / t ** 2


def E_surface(extent, pts, nrm, L, dA, chunk=64):
    """Irradiance from emitter samples (one-sided, normal nrm); L(pts, dirs) or scalar."""
    x, y = pixel_points(extent)
    R = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], -1)
    out = np.empty(len(R))
    for i in range(0, len(R), chunk):
        d = pts[None] - R[i:i + chunk, None]  # receiver -> emitter
        t = np.linalg.norm(d, axis=-1)
        w = d / t[..., None]
        cos_r = np.clip(w[..., 2], 0, None)
        cos_l = np.clip(-(w * nrm[None]).sum(-1), 0, None)
        Lv = L(pts, -w) if callable(L) else L
        out[i:i + chunk] = (Lv * cos_r * cos_l / t ** 2).sum(-1) * dA
    return out.reshape(x.shape)


def grid(n):
    return (np.arange(n) + 0.5) / n - 0.5


def rect_samples(sx, sy, z, n=120):
    u, v = np.meshgrid(grid(n) * sx, grid(n) * sy)
    pts = np.stack([u.ravel(), v.ravel(), np.full(u.size, z)], -1)
    nrm = np.tile([0.0, 0.0, -1.0], (len(pts), 1))
    return pts, nrm, sx * sy / n ** 2


def ellipse_samples(sx, sy, z, n=160):
    pts, nrm, dA = rect_samples(sx, sy, z, n)
    keep = (pts[:, 0] / (sx / 2)) ** 2 + (pts[:, 1] / (sy / 2)) ** 2 <= 1
    return pts[keep], nrm[keep], dA


def sphere_samples(r, c, n=20000):
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    th = math.pi * (1 + 5 ** 0.5) * i
    nrm = np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], -1)
    return np.asarray(c) + r * nrm, nrm, 4 * math.pi * r * r / n


def E_soft_disk(extent, P, h, r, size=None, blend=0.0, n=40):
    """Disk of radius r at the light, always facing the receiver, radiance P/(4 pi^2 r^2)."""
    x, y = pixel_points(extent)
    L = P / (4 * math.pi ** 2 * r * r)
    u, v = np.meshgrid(grid(n) * 2, grid(n) * 2)
    keep = u ** 2 + v ** 2 <= 1
    u, v = u[keep] * r, v[keep] * r
    dA = math.pi * r * r / keep.sum()  # exact disk area, not the staircase's
    E = np.zeros(x.shape)
    c = np.array([0, 0, h])
    for j in range(RES):
        for i in range(RES):
            Rp = np.array([x[j, i], y[j, i], 0.0])
            a = (Rp - c) / np.linalg.norm(Rp - c)
            e1 = np.cross(a, [1, 0, 0] if abs(a[0]) < 0.9 else [0, 1, 0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(a, e1)
            pts = c + u[:, None] * e1 + v[:, None] * e2
            d = pts - Rp
            t = np.linalg.norm(d, axis=-1)
            w = d / t[:, None]
            att = 1.0 if size is None else spot_att(-w, size, blend)
            E[j, i] = (L * att * np.clip(w[:, 2], 0, None) *
                       np.clip((-w * a).sum(-1), 0, None) / t ** 2).sum() * dA
    return E


def E_sun_cone(S, tilt, angle, n=200000, hyp="solid_angle"):
    """Plane irradiance from a uniform-radiance disc of full angle `angle`."""
    a = angle / 2
    rng = np.random.default_rng(1)
    cosv = 1 - rng.random(n) * (1 - math.cos(a))
    sinv = np.sqrt(1 - cosv ** 2)
    ph = rng.random(n) * 2 * math.pi
    d = np.stack([sinv * np.cos(ph), sinv * np.sin(ph), cosv], -1)
    ct, st = math.cos(tilt), math.sin(tilt)
    dz = -d[:, 1] * st + d[:, 2] * ct  # rotate about x by tilt
    omega = 2 * math.pi * (1 - math.cos(a))
    L = S / (math.pi * math.sin(a) ** 2) if hyp == "projected" else S / omega
    return L * np.clip(dz, 0, None).mean() * omega


# ------------------------------------------------------------------- the cases
CASES = []


def case(name, spp=64):
    def deco(fn):
        CASES.append((name, spp, fn))
        return fn
    return deco


@case("point r=0, Diffuse BSDF", spp=4)
def _():
    s = setup(4.0)
    add_light(s, "POINT", 1000, (0, 0, 1))
    return s, radiance(E_point(4.0, 1000, 1.0))


for kind in ("PRINCIPLED_DEFAULT", "PRINCIPLED_R1", "PRINCIPLED_R1_NOSPEC"):
    @case("point r=0, " + kind, spp=64)
    def _(kind=kind):
        s = setup(4.0, plane_kind=kind)
        add_light(s, "POINT", 1000, (0, 0, 1))
        return s, radiance(E_point(4.0, 1000, 1.0))

for soft in (True, False):
    for k in (2, 5, 50):
        @case("point r=0.1 h=%dr soft=%s" % (k, soft), spp=256)
        def _(soft=soft, k=k):
            r, h = 0.1, 0.1 * k
            ext = 8 * h
            s = setup(ext)
            add_light(s, "POINT", 100, (0, 0, h), shadow_soft_size=r, use_soft_falloff=soft)
            E = E_soft_disk(ext, 100, h, r) if soft else E_point(ext, 100, h)
            return s, radiance(E)

for soft in (True, False):
    @case("point r=0.5 seen by camera soft=%s (pixel = P/(4 pi^2 r^2) + plane)" % soft,
          spp=64)
    def _(soft=soft):
        # Lights do not occlude: the camera ray adds L and goes on to the plane.
        s = setup(0.4)
        ob = add_light(s, "POINT", 100, (0, 0, 2), shadow_soft_size=0.5, use_soft_falloff=soft)
        ob.visible_camera = True
        E = E_soft_disk(0.4, 100, 2, 0.5) if soft else E_point(0.4, 100, 2)
        return s, radiance(E) + 100 / (4 * math.pi ** 2 * 0.25)

@case("point r=0.2 normalize=False (pred: sphere radiance L = P/pi)", spp=256)
def _():
    s = setup(4.0)
    add_light(s, "POINT", 100, (0, 0, 1), shadow_soft_size=0.2, use_soft_falloff=False,
              normalize=False)
    # A sphere of radiance P/pi acts like a point of power P * 4 pi r^2.
    return s, radiance(E_point(4.0, 100 * 4 * math.pi * 0.2 ** 2, 1.0))

for blend in (0.0, 0.15, 0.5, 1.0):
    @case("spot r=0 size=60deg blend=%g" % blend, spp=16)
    def _(blend=blend):
        s = setup(3.0)
        add_light(s, "SPOT", 1000, (0, 0, 1), spot_size=math.radians(60), spot_blend=blend)
        return s, radiance(E_point(3.0, 1000, 1.0, math.radians(60), blend))

for soft in (True, False):
    @case("spot r=0.2 size=60deg blend=0.3 soft=%s" % soft, spp=256)
    def _(soft=soft):
        s = setup(3.0)
        size, blend, r, h = math.radians(60), 0.3, 0.2, 1.0
        add_light(s, "SPOT", 1000, (0, 0, h), spot_size=size, spot_blend=blend,
                  shadow_soft_size=r, use_soft_falloff=soft)
        if soft:
            return s, radiance(E_soft_disk(3.0, 1000, h, r, size, blend))
        pts, nrm, dA = sphere_samples(r, (0, 0, h))
        L = 1000 / (4 * math.pi ** 2 * r * r)
        return s, radiance(E_surface(3.0, pts, nrm, lambda p, w: L * spot_att(w, size, blend), dA))

AREAS = [("SQUARE", 1.0, 1.0, (1, 1, 1)), ("RECTANGLE", 1.0, 0.5, (1, 1, 1)),
         ("DISK", 1.0, 1.0, (1, 1, 1)), ("ELLIPSE", 1.0, 0.5, (1, 1, 1)),
         ("SQUARE", 1.0, 1.0, (2, 1.5, 1)), ("ELLIPSE", 1.0, 0.5, (1.5, 2, 1))]
for shape, sx, sy, sc in AREAS:
    @case("area %s %gx%g scale=%s" % (shape, sx, sy, sc[:2]), spp=256)
    def _(shape=shape, sx=sx, sy=sy, sc=sc):
        s = setup(4.0)
        ob = add_light(s, "AREA", 100, (0, 0, 1), shape=shape, size=sx, size_y=sy)
        ob.scale = sc
        sx, sy = sx * sc[0], sy * sc[1]
        disk = shape in ("DISK", "ELLIPSE")
        pts, nrm, dA = (ellipse_samples if disk else rect_samples)(sx, sy, 1.0)
        A = math.pi * sx * sy / 4 if disk else sx * sy
        return s, radiance(E_surface(4.0, pts, nrm, 100 / (math.pi * A), dA))

for size in (0.5, 2.0):
    @case("area SQUARE size=%g normalize=False (pred: L = P/pi)" % size, spp=256)
    def _(size=size):
        s = setup(4.0)
        add_light(s, "AREA", 100, (0, 0, 1), shape="SQUARE", size=size, normalize=False)
        pts, nrm, dA = rect_samples(size, size, 1.0)
        return s, radiance(E_surface(4.0, pts, nrm, 100 / math.pi, dA))

def spread_att(cos_a, spread):
    """Soft-box slats: (tan(spread/2) - tan a)+, scaled so that the power stays P."""
    th = np.linspace(0, math.pi / 2, 20001)[1:-1]
    f = lambda c: np.clip(math.tan(spread / 2) - np.sqrt(1 - c * c) / c, 0, None)
    norm = np.trapz(f(np.cos(th)) * np.cos(th) * np.sin(th), th) * 2  # = 1 for spread 180
    return f(np.clip(cos_a, 1e-9, 1)) / norm


for spread in (90, 150):
    @case("area SQUARE spread=%ddeg (pred: soft-box slats, power kept)" % spread, spp=512)
    def _(spread=spread):
        s = setup(4.0)
        sp = math.radians(spread)
        add_light(s, "AREA", 100, (0, 0, 1), shape="SQUARE", size=1.0, spread=sp)
        pts, nrm, dA = rect_samples(1.0, 1.0, 1.0)
        L = lambda p, w: 100 / math.pi * spread_att(-w[..., 2], sp)
        return s, radiance(E_surface(4.0, pts, nrm, L, dA))


@case("area SQUARE facing up (back side, pred 0)", spp=64)
def _():
    s = setup(4.0)
    add_light(s, "AREA", 100, (0, 0, 1), rot=(math.pi, 0, 0), shape="SQUARE", size=1.0)
    return s, np.zeros((RES, RES, 3))

@case("point exposure=1 (pred 2x)", spp=4)
def _():
    s = setup(4.0)
    add_light(s, "POINT", 1000, (0, 0, 1), exposure=1.0)
    return s, 2 * radiance(E_point(4.0, 1000, 1.0))

@case("point color=(1,.5,.25) temperature=3000", spp=4)
def _():
    s = setup(4.0)
    ob = add_light(s, "POINT", 1000, (0, 0, 1), color=(1, 0.5, 0.25),
                   use_temperature=True, temperature=3000)
    tc = np.array(ob.data.temperature_color) * [1, 0.5, 0.25]
    return s, radiance(E_point(4.0, 1000, 1.0)) * tc

for tilt, ang in ((30, 0), (0, 60), (60, 40)):
    @case("sun tilt=%d angle=%d strength=3 (pred: uniform disc, E_normal = S)" % (tilt, ang),
          spp=256)
    def _(tilt=tilt, ang=ang):
        s = setup(4.0)
        add_light(s, "SUN", 3.0, (0, 0, 5), rot=(math.radians(tilt), 0, 0),
                  angle=math.radians(ang))
        E = (3.0 * math.cos(math.radians(tilt)) if ang == 0 else
             E_sun_cone(3.0, math.radians(tilt), math.radians(ang), hyp="projected"))
        return s, radiance(np.full((RES, RES), E))

for principled in (False, True):
    for flip in (False, True):
        @case("emissive quad (%s) %s (pred two-sided L=c*s)" % (
            "Principled" if principled else "Emission", "facing up" if flip else "facing down"),
            spp=256)
        def _(principled=principled, flip=flip):
            s = setup(4.0)
            c, st = (1.0, 0.5, 0.25), 4.0
            quad(s, "emitter", 1.0, 1.0, 1.0, emission_material(c, st, principled), flip=not flip)
            pts, nrm, dA = rect_samples(1.0, 1.0, 1.0)
            E = E_surface(4.0, pts, nrm, 1.0, dA)
            # Two-sided: the plane is lit whichever way the quad faces, and the
            # camera sees radiance c*s on whichever side faces it.
            x, y = pixel_points(4.0)
            inside = ((abs(x) < 0.5) & (abs(y) < 0.5))[..., None]
            return s, np.where(inside, np.array(c) * st, radiance(E) * np.array(c) * st)

@case("world colour (.2,.4,.8) strength 2: plane 1x1 = rho*c*s, background = c*s", spp=256)
def _():
    s = setup(2.0)
    s.objects["plane"].scale = (1 / 400, 1 / 400, 1)
    bg = s.world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.2, 0.4, 0.8, 1)
    bg.inputs["Strength"].default_value = 2.0
    x, y = pixel_points(2.0)
    inside = ((abs(x) < 0.5) & (abs(y) < 0.5))[..., None]
    c = np.array([0.2, 0.4, 0.8]) * 2
    return s, np.where(inside, RHO * c, c)


def run(filters=()):
    print("%-66s %8s %9s %9s %9s" % ("case", "ratio", "relMSE", "maxrel", "sec"))
    for name, spp, fn in CASES:
        if filters and not any(f.lower() in name.lower() for f in filters):
            continue
        scene, pred = fn()
        reference.configure_cycles(scene, spp, direct_only=True, pixel_filter="CENTER")
        img, sec = reference.timed_render(scene)
        ratio = img.sum() / pred.sum() if pred.sum() > 0 else float("nan")
        bright = pred > 0.05 * pred.max() if pred.max() > 0 else np.ones(pred.shape, bool)
        maxrel = (np.abs(img - pred)[bright] / np.maximum(pred[bright], 1e-6)).max() \
            if pred.max() > 0 else float(np.abs(img).max())
        print("%-66s %8.4f %9.2e %9.2e %9.1f" % (name[:66], ratio, metrics.relmse(img, pred),
                                                 maxrel, sec), flush=True)


if __name__ == "__main__":
    run(sys.argv[1:])
