"""Deterministic test and benchmark scenes, built purely from code.

Every builder fills the current (already reset) bpy scene, sets the camera and
a square resolution, tags scene["irad_scene_key"] for the reference cache and
returns the scene. All surfaces are Lambertian: a Diffuse BSDF with roughness 0,
which Cycles renders exactly as rho/pi (Principled adds a specular layer unless
its Specular IOR Level is 0; see docs/radiometry.md).

Images (reference.render_image) are (H, W, 3) float32 with row 0 = TOP.
"""
import math

import bpy
import numpy as np

WHITE, RED, GREEN = (0.75, 0.75, 0.75), (0.63, 0.065, 0.05), (0.14, 0.45, 0.091)


# ------------------------------------------------------------------ helpers
def _scene(key, resolution):
    scene = bpy.context.scene
    scene["irad_scene_key"] = key
    r = scene.render
    r.resolution_x = r.resolution_y = int(resolution)
    r.resolution_percentage = 100
    world(scene, (0.0, 0.0, 0.0), 0.0)
    return scene


def world(scene, color, strength):
    """Constant world. world.use_nodes is deprecated in 5.0; new worlds already
    have a node tree with a Background node, which Cycles uses."""
    w = bpy.data.worlds.new("World")
    bg = w.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    w.color = color  # viewport only
    scene.world = w
    return w


def diffuse(name, color):
    m = bpy.data.materials.new(name)
    nt = m.node_tree
    nt.nodes.remove(nt.nodes["Principled BSDF"])
    d = nt.nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (*color, 1.0)
    d.inputs["Roughness"].default_value = 0.0
    nt.links.new(d.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    m.diffuse_color = (*color, 1.0)
    return m


def emissive_diffuse(name, albedo, emission, color=(1.0, 1.0, 1.0)):
    """Diffuse(albedo) + Emission(color * emission): radiance adds, both sides emit."""
    m = diffuse(name, (albedo,) * 3)
    nt = m.node_tree
    d = nt.nodes["Diffuse BSDF"]
    e = nt.nodes.new("ShaderNodeEmission")
    e.inputs["Color"].default_value = (*color, 1.0)
    e.inputs["Strength"].default_value = emission
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(d.outputs[0], add.inputs[0])
    nt.links.new(e.outputs[0], add.inputs[1])
    nt.links.new(add.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    return m


def mirror(name):
    m = bpy.data.materials.new(name)
    p = m.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    p.inputs["Metallic"].default_value = 1.0
    p.inputs["Roughness"].default_value = 0.0
    m.diffuse_color, m.metallic, m.roughness = (1, 1, 1, 1), 1.0, 0.0
    return m


def mesh(scene, name, verts, faces, material, loc=(0, 0, 0), rot_z=0.0):
    """Mesh from vertices (N, 3) and quads (M, 4) (numpy, fast for millions)."""
    v = np.asarray(verts, dtype=np.float32).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int32).reshape(-1, 4)
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(v))
    me.vertices.foreach_set("co", v.ravel())
    me.loops.add(f.size)
    me.loops.foreach_set("vertex_index", f.ravel())
    me.polygons.add(len(f))
    me.polygons.foreach_set("loop_start", np.arange(0, f.size, 4, dtype=np.int32))
    me.update()
    # Without a sharp_face attribute Blender >= 4.1 shades smooth: vertex normals
    # averaged over a box's 90 degree edges lose ~10% energy in Cycles. Keep facets flat.
    me.shade_flat()
    me.materials.append(material)
    ob = bpy.data.objects.new(name, me)
    ob.location = loc
    ob.rotation_euler = (0.0, 0.0, rot_z)
    scene.collection.objects.link(ob)
    return ob


def quad(scene, name, corners, material):
    """One quad; corners counter-clockwise seen from the side its normal faces."""
    return mesh(scene, name, corners, [[0, 1, 2, 3]], material)


def box(scene, name, size, material, loc=(0, 0, 0), rot_z=0.0, inward=False):
    """Closed axis-aligned box centred at loc (bottom at loc.z - size.z / 2)."""
    sx, sy, sz = (s / 2 for s in size)
    v = [(x, y, z) for z in (-sz, sz) for y in (-sy, sy) for x in (-sx, sx)]
    f = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    if inward:
        f = [q[::-1] for q in f]
    return mesh(scene, name, v, f, material, loc, rot_z)


def grid_plane(scene, name, size, material, z=0.0):
    h = size / 2
    return quad(scene, name, [(-h, -h, z), (h, -h, z), (h, h, z), (-h, h, z)], material)


def camera(scene, loc, rot, lens_deg=None, ortho_scale=None):
    cam = bpy.data.cameras.new("Camera")
    if ortho_scale is not None:
        cam.type = "ORTHO"
        cam.ortho_scale = ortho_scale
    else:
        cam.angle = math.radians(lens_deg)  # full field of view of the wider side
    cam.clip_start, cam.clip_end = 0.01, 1000.0
    ob = bpy.data.objects.new("Camera", cam)
    ob.location = loc
    ob.rotation_euler = rot
    scene.collection.objects.link(ob)
    scene.camera = ob
    return ob


def light(scene, kind, energy, loc, rot=(0, 0, 0), **props):
    ld = bpy.data.lights.new("Light", kind)
    ld.energy = energy
    for k, v in props.items():
        setattr(ld, k, v)
    ob = bpy.data.objects.new("Light", ld)
    ob.location, ob.rotation_euler = loc, rot
    scene.collection.objects.link(ob)
    return ob


LOOK_Y = (math.pi / 2, 0.0, 0.0)  # camera rotation looking along +y, z up


# ------------------------------------------------------------- Cornell box
def _cornell(scene, left_mat=None, right_mat=None, back_mat=None):
    """Box [-1, 1]^3, open at y = -1; returns nothing (objects linked)."""
    white = diffuse("white", WHITE)
    left_mat = left_mat or diffuse("red", RED)
    right_mat = right_mat or diffuse("green", GREEN)
    back_mat = back_mat or white
    quad(scene, "floor", [(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1)], white)
    quad(scene, "ceiling", [(-1, -1, 1), (-1, 1, 1), (1, 1, 1), (1, -1, 1)], white)
    quad(scene, "back", [(-1, 1, -1), (1, 1, -1), (1, 1, 1), (-1, 1, 1)], back_mat)
    quad(scene, "left", [(-1, -1, -1), (-1, 1, -1), (-1, 1, 1), (-1, -1, 1)], left_mat)
    quad(scene, "right", [(1, -1, -1), (1, -1, 1), (1, 1, 1), (1, 1, -1)], right_mat)
    box(scene, "short_box", (0.6, 0.6, 0.6), white, (0.35, -0.3, -0.7), math.radians(-17))
    box(scene, "tall_box", (0.6, 0.6, 1.2), white, (-0.35, 0.3, -0.4), math.radians(17))
    # Field of view exactly spans the open front face (half-width 1 at distance 2.9).
    camera(scene, (0, -3.9, 0), LOOK_Y, lens_deg=2 * math.degrees(math.atan(1 / 2.9)))


def _cornell_light(scene, kind):
    if kind == "AREA":
        # One-sided square, pointing down (-z), just below the ceiling.
        light(scene, "AREA", 40.0, (0, 0, 0.98), shape="SQUARE", size=0.5)
    elif kind == "POINT":
        light(scene, "POINT", 35.0, (0, 0, 0.8))
    else:
        raise ValueError(kind)


def cornell_box(light="AREA", resolution=128):
    scene = _scene("cornell_box:%s" % light, resolution)
    _cornell(scene)
    _cornell_light(scene, light)
    return scene


def mirror_box(resolution=96, light="AREA"):
    """Cornell box whose back wall is a perfect mirror."""
    scene = _scene("mirror_box" if light == "AREA" else "mirror_box:%s" % light, resolution)
    _cornell(scene, back_mat=mirror("mirror"))
    _cornell_light(scene, light)
    return scene


# --------------------------------------------------------- plane + one light
LIGHT_KINDS = ("POINT", "POINT_RADIUS", "SPOT", "AREA_SQUARE", "AREA_RECTANGLE",
               "AREA_DISK", "AREA_ELLIPSE", "SUN", "SUN_ANGLE", "EMISSIVE_MESH", "WORLD")


def plane_with_light(kind, resolution=64):
    """Plane (albedo 0.8) with an occluder box and one light, camera at 45 degrees."""
    scene = _scene("plane_with_light:%s" % kind, resolution)
    grid_plane(scene, "plane", 40.0, diffuse("plane", (0.8, 0.8, 0.8)))
    box(scene, "occluder", (0.4, 0.4, 0.4), diffuse("occluder", (0.8, 0.8, 0.8)),
        (0.3, 0.2, 0.2), math.radians(20))
    camera(scene, (0, -4.2, 4.2), (math.radians(45), 0, 0), lens_deg=55)
    tilt = (math.radians(25), math.radians(-15), 0)  # slanted so shadows are long
    h = (0, 0, 1.5)
    if kind == "POINT":
        light(scene, "POINT", 150.0, (-0.3, -0.3, 1.5))
    elif kind == "POINT_RADIUS":
        light(scene, "POINT", 150.0, (-0.3, -0.3, 1.5), shadow_soft_size=0.25)
    elif kind == "SPOT":
        light(scene, "SPOT", 300.0, (-0.6, -0.6, 2.0), (math.radians(-20), math.radians(-20), 0),
              spot_size=math.radians(70), spot_blend=0.3)
    elif kind.startswith("AREA_"):
        shape = kind[5:]
        light(scene, "AREA", 150.0, h, tilt, shape=shape, size=0.8,
              size_y=0.4 if shape in ("RECTANGLE", "ELLIPSE") else 0.8)
    elif kind == "SUN":
        light(scene, "SUN", 3.0, (0, 0, 5), tilt)
    elif kind == "SUN_ANGLE":
        light(scene, "SUN", 3.0, (0, 0, 5), tilt, angle=math.radians(10))
    elif kind == "EMISSIVE_MESH":
        m = bpy.data.materials.new("emitter")
        nt = m.node_tree
        nt.nodes.remove(nt.nodes["Principled BSDF"])
        e = nt.nodes.new("ShaderNodeEmission")
        e.inputs["Strength"].default_value = 20.0
        nt.links.new(e.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
        m.diffuse_color = (1, 1, 1, 1)
        # Normal points down at the plane (emission is two-sided in Cycles anyway).
        quad(scene, "emitter", [(-0.4, -0.4, 1.5), (-0.4, 0.4, 1.5), (0.4, 0.4, 1.5),
                                (0.4, -0.4, 1.5)], m)
    elif kind == "WORLD":
        world(scene, (0.5, 0.6, 0.8), 1.0)
    else:
        raise ValueError(kind)
    return scene


# ---------------------------------------------------------------- analytic
def furnace(albedo=0.5, emission=1.0, resolution=32):
    """Closed box seen from inside; every face emits `emission` and reflects `albedo`.
    Expected radiance everywhere: emission / (1 - albedo)."""
    scene = _scene("furnace:%g:%g" % (albedo, emission), resolution)
    box(scene, "furnace", (2, 2, 2), emissive_diffuse("furnace", albedo, emission),
        (0, 0, 0), inward=True)
    camera(scene, (0.1, -0.2, 0.05), (math.radians(80), 0, math.radians(10)), lens_deg=70)
    scene["irad_expected_radiance"] = emission / (1.0 - albedo)
    return scene


def point_over_plane(height=1.0, power=1000.0, resolution=64, offset=(0.0, 0.0)):
    """Point light (radius 0) at (offset, height) over a 400 x 400 plane (albedo 0.8),
    orthographic camera centred on the origin looking straight down, covering
    4 * height. An offset light makes the image asymmetric (catches flips)."""
    key = "point_over_plane:%g:%g:%g:%g" % (height, power, *offset)
    scene = _scene(key, resolution)
    scene["irad_albedo"] = 0.8
    grid_plane(scene, "plane", 400.0, diffuse("plane", (0.8, 0.8, 0.8)))
    light(scene, "POINT", power, (offset[0], offset[1], height), shadow_soft_size=0.0)
    # Identity rotation: looks down -z, image right = +x, image up = +y.
    camera(scene, (0, 0, height + 10.0), (0, 0, 0), ortho_scale=4.0 * height)
    return scene


def point_over_plane_analytic(scene):
    """Expected image (H, W, 3), row 0 = top: L = rho/pi * (P/4pi) cos(theta) / d^2
    at each pixel centre (x = (i + 0.5) / W, y from the top, mapped to world)."""
    cam = scene.camera
    lamp = next(o for o in scene.objects if o.type == "LIGHT")
    W, H = scene.render.resolution_x, scene.render.resolution_y
    s = cam.data.ortho_scale
    sx, sy = (s, s * H / W) if W >= H else (s * W / H, s)
    x = cam.location.x + ((np.arange(W) + 0.5) / W - 0.5) * sx
    y = cam.location.y - ((np.arange(H) + 0.5) / H - 0.5) * sy  # row 0 = top = +y
    X, Y = np.meshgrid(x, y)
    lx, ly, h = lamp.location
    d2 = (X - lx) ** 2 + (Y - ly) ** 2 + h * h
    I = lamp.data.energy / (4 * math.pi)
    L = scene["irad_albedo"] / math.pi * I * (h / np.sqrt(d2)) / d2
    return np.repeat(L[..., None], 3, axis=2).astype(np.float32)


# ------------------------------------------------------------- benchmarks
def two_rooms(resolution=96):
    """Two 2 x 2 x 2 rooms side by side joined by a doorway; the light is in the
    far room, so the camera's room is lit only indirectly."""
    scene = _scene("two_rooms", resolution)
    white, wall = diffuse("white", WHITE), diffuse("wall", (0.7, 0.65, 0.55))
    box(scene, "room_a", (2, 2, 2), white, (0, 0, 0), inward=True)
    box(scene, "room_b", (2, 2, 2), wall, (2.02, 0, 0), inward=True)
    # Open a doorway: replace the two facing walls by walls with a hole, built as quads.
    for ob in (scene.objects["room_a"], scene.objects["room_b"]):
        _remove_face(ob, +1 if ob.name == "room_a" else -1)
    for x in (1.0, 1.02):
        for q in ([(x, -1, -1), (x, -0.3, -1), (x, -0.3, 1), (x, -1, 1)],
                  [(x, 0.3, -1), (x, 1, -1), (x, 1, 1), (x, 0.3, 1)],
                  [(x, -0.3, 0.5), (x, 0.3, 0.5), (x, 0.3, 1), (x, -0.3, 1)]):
            quad(scene, "door_wall", q, white)
    for y in (-0.3, 0.3):  # door jambs close the gap between the two walls
        quad(scene, "jamb", [(1.0, y, -1), (1.02, y, -1), (1.02, y, 0.5), (1.0, y, 0.5)], white)
    quad(scene, "lintel", [(1.0, -0.3, 0.5), (1.02, -0.3, 0.5), (1.02, 0.3, 0.5),
                           (1.0, 0.3, 0.5)], white)
    box(scene, "cube", (0.5, 0.5, 0.5), diffuse("blue", (0.1, 0.2, 0.6)), (-0.4, 0.3, -0.75),
        math.radians(30))
    light(scene, "AREA", 60.0, (2.3, 0.4, 0.97), shape="SQUARE", size=0.5)
    camera(scene, (-0.9, -0.9, 0.2), (math.radians(88), 0, math.radians(-62)), lens_deg=75)
    return scene


def _remove_face(ob, side):
    """Drop the box face at x = +1 (side 1) or x = -1 (side -1) in local space."""
    import bmesh
    bm = bmesh.new()
    bm.from_mesh(ob.data)
    faces = [f for f in bm.faces if all(abs(v.co.x - side) < 1e-6 for v in f.verts)]
    bmesh.ops.delete(bm, geom=faces, context="FACES")
    bm.to_mesh(ob.data)
    bm.free()


def sunlit_room(resolution=96, portal=False):
    """Closed 4 x 4 x 2.5 room with a window in one wall; a sun shines through it.
    portal: a Cycles light portal fills the window (it does not change the image)."""
    scene = _scene("sunlit_room:portal" if portal else "sunlit_room", resolution)
    white, floor = diffuse("white", WHITE), diffuse("floor", (0.55, 0.4, 0.3))
    quad(scene, "floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], floor)
    quad(scene, "ceiling", [(-2, -2, 2.5), (-2, 2, 2.5), (2, 2, 2.5), (2, -2, 2.5)], white)
    quad(scene, "wall_n", [(-2, 2, 0), (2, 2, 0), (2, 2, 2.5), (-2, 2, 2.5)], white)
    quad(scene, "wall_s", [(-2, -2, 0), (-2, -2, 2.5), (2, -2, 2.5), (2, -2, 0)], white)
    quad(scene, "wall_w", [(-2, -2, 0), (-2, 2, 0), (-2, 2, 2.5), (-2, -2, 2.5)], white)
    # East wall (x = 2) with a 1.6 x 1.0 window from y -0.8..0.8, z 0.8..1.8.
    x = 2.0
    for q in ([(x, -2, 0), (x, -2, 2.5), (x, -0.8, 2.5), (x, -0.8, 0)],
              [(x, 0.8, 0), (x, 0.8, 2.5), (x, 2, 2.5), (x, 2, 0)],
              [(x, -0.8, 0), (x, -0.8, 0.8), (x, 0.8, 0.8), (x, 0.8, 0)],
              [(x, -0.8, 1.8), (x, -0.8, 2.5), (x, 0.8, 2.5), (x, 0.8, 1.8)]):
        quad(scene, "wall_e", q, white)
    box(scene, "table", (0.8, 0.8, 0.7), diffuse("table", (0.6, 0.6, 0.5)), (-0.5, 0.3, 0.35))
    # Sun from the east, 35 degrees above the horizon: light travels along -x and down.
    light(scene, "SUN", 40.0, (4, 0, 3), (0, math.radians(55), 0), angle=math.radians(0.5))
    camera(scene, (-1.8, -1.8, 1.4), (math.radians(80), 0, math.radians(-50)), lens_deg=80)
    if portal:
        window_portal(scene, (x, 0, 1.3), 1.6, 1.0)
    return scene


def window_portal(scene, center, width, height):
    """A portal in a window of the wall x = center.x, letting light in along -x:
    local -Z (the way light passes) turned to -x, local X to -z (height), Y to y (width)."""
    ob = light(scene, "AREA", 0.0, center, (0, math.radians(90), 0), shape="RECTANGLE",
               size=height, size_y=width)
    ob.name = "portal"
    ob.data.cycles.is_portal = True
    return ob


def high_poly(triangles=1_000_000, resolution=96):
    """Floor plus 4 UV spheres with `triangles` triangles in total, lit by an area light."""
    scene = _scene("high_poly:%d" % triangles, resolution)
    grid_plane(scene, "floor", 20.0, diffuse("floor", WHITE))
    per = max(triangles // 4, 8)
    n = max(int(math.sqrt(per / 4)), 2)  # n rings x 2n segments, 2 triangles per quad
    colours = [(0.8, 0.3, 0.2), (0.2, 0.6, 0.3), (0.3, 0.4, 0.8), (0.75, 0.75, 0.75)]
    for i, col in enumerate(colours):
        v, f = _uv_sphere(n, 2 * n, 0.45)
        mesh(scene, "sphere%d" % i, v, f, diffuse("s%d" % i, col),
             ((i - 1.5) * 1.05, 0.2 * (i % 2), 0.45))
    light(scene, "AREA", 200.0, (0, -1.0, 3.0), (math.radians(-20), 0, 0), shape="SQUARE",
          size=1.5)
    world(scene, (0.05, 0.05, 0.06), 1.0)
    camera(scene, (0, -4.5, 2.2), (math.radians(68), 0, 0), lens_deg=60)
    return scene


def _uv_sphere(rings, segs, r):
    """Closed UV sphere as quads (pole rows are degenerate quads: fine for Cycles)."""
    th = np.linspace(0, math.pi, rings + 1)
    ph = np.linspace(0, 2 * math.pi, segs + 1)[:-1]
    T, P = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([r * np.sin(T) * np.cos(P), r * np.sin(T) * np.sin(P), r * np.cos(T)], -1)
    i, j = np.meshgrid(np.arange(rings), np.arange(segs), indexing="ij")
    a = i * segs + j
    b = i * segs + (j + 1) % segs
    f = np.stack([a, a + segs, b + segs, b], -1).reshape(-1, 4)
    return v.reshape(-1, 3), f
