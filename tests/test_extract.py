"""extract.py against real scenes built with bpy (headless), checked against known numbers."""
import math
import time

import bpy
import numpy as np
import pytest


@pytest.fixture
def ex(addon):
    """The installed add-on's extract module (conftest blocks the checkout's copy)."""
    return addon.irad_addon.extract


def dg_viewport():
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    return dg


class _Capture(bpy.types.RenderEngine):
    """A throwaway engine: runs a callback on the RENDER depsgraph of a 4x4 render."""
    bl_idname = "IRAD_TEST_CAPTURE"
    bl_label = "irad test capture"
    callback = None

    def render(self, depsgraph):
        type(self).callback(depsgraph)
        r = depsgraph.scene.render
        w = r.resolution_x * r.resolution_percentage // 100
        h = r.resolution_y * r.resolution_percentage // 100
        self.end_result(self.begin_result(0, 0, w, h))


def extract_render(ex, scene, **kw):
    """extract_scene on a real RENDER depsgraph (needs a camera)."""
    out = {}
    if scene.camera is None:
        add_camera(scene)
    bpy.utils.register_class(_Capture)
    engine, x, y, pct = (scene.render.engine, scene.render.resolution_x,
                         scene.render.resolution_y, scene.render.resolution_percentage)
    try:
        _Capture.callback = lambda dg: out.update(sd=ex.extract_scene(dg, **kw), mode=dg.mode)
        scene.render.engine = _Capture.bl_idname
        scene.render.resolution_x = scene.render.resolution_y = 4
        scene.render.resolution_percentage = 100
        bpy.ops.render.render()
    finally:
        scene.render.engine = engine
        scene.render.resolution_x, scene.render.resolution_y = x, y
        scene.render.resolution_percentage = pct
        bpy.utils.unregister_class(_Capture)
    assert out["mode"] == "RENDER"
    return out["sd"]


def add_camera(scene, name="Cam", **props):
    cam = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    scene.collection.objects.link(cam)
    for k, v in props.items():
        setattr(cam.data, k, v)
    scene.camera = cam
    return cam


def add_cube(name="Cube", location=(0, 0, 0), size=2.0):
    bpy.ops.mesh.primitive_cube_add(size=size, location=location)
    ob = bpy.context.object
    ob.name = name
    return ob


def tris_of(sd, name):
    i = sd.mesh.object_names.index(name)
    return sd.mesh.triangles[sd.mesh.object_index == i]


def geometric_normals(tris):
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def material(name, kind="Principled BSDF", **inputs):
    """A node material whose output is fed by a single node of the given kind."""
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    for n in list(tree.nodes):
        if n != out:
            tree.nodes.remove(n)
    node = tree.nodes.new({"Principled BSDF": "ShaderNodeBsdfPrincipled",
                           "Diffuse": "ShaderNodeBsdfDiffuse",
                           "Glossy": "ShaderNodeBsdfGlossy",
                           "Emission": "ShaderNodeEmission"}[kind])
    for k, v in inputs.items():
        node.inputs[k].default_value = v
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    return mat, node


def assign(ob, *mats):
    ob.data.materials.clear()
    for m in mats:
        ob.data.materials.append(m)


# ------------------------------------------------------------------------- geometry

def test_subdivision_modifier_comes_from_the_evaluated_mesh(ex, scene):
    cube = add_cube()
    mod = cube.modifiers.new("Subd", "SUBSURF")
    mod.levels = mod.render_levels = 1
    mod.use_limit_surface = False          # plain Catmull-Clark: positions are known
    for sd in (ex.extract_scene(dg_viewport()), extract_render(ex, scene)):
        m = sd.mesh
        assert m.triangle_count == 6 * 4 * 2
        assert m.triangles.dtype == np.float32 and m.triangles.shape == (48, 3, 3)
        assert m.corner_normals.dtype == np.float32 and m.corner_normals.shape == (48, 3, 3)
        assert m.material_index.dtype == np.int32 and m.object_index.dtype == np.int32
        flat = m.triangles.reshape(-1, 3)
        np.testing.assert_allclose(flat.min(0), -1, atol=1e-6)   # face points stay on faces
        np.testing.assert_allclose(flat.max(0), 1, atol=1e-6)
        # Catmull-Clark moves a cube corner (valence 3) to 5/9 of its position.
        d = np.abs(np.abs(flat) - 5 / 9).max(axis=1)
        assert d.min() < 1e-6
        assert np.abs(flat).max(axis=1).min() > 0.5       # no original corner (1,1,1) left
        assert m.object_names == ["Cube"]


def test_array_modifier(ex, scene):
    cube = add_cube()
    arr = cube.modifiers.new("Array", "ARRAY")
    arr.count = 3
    arr.relative_offset_displace = (1.5, 0, 0)
    sd = ex.extract_scene(dg_viewport())
    assert sd.mesh.triangle_count == 36
    flat = sd.mesh.triangles.reshape(-1, 3)
    np.testing.assert_allclose(flat.min(0), (-1, -1, -1), atol=1e-6)
    np.testing.assert_allclose(flat.max(0), (-1 + 2 * 1.5 * 2 + 2, 1, 1), atol=1e-5)


def test_collection_instances_are_triangulated_once(ex, scene):
    src = bpy.data.collections.new("Src")            # not linked to the scene
    cube = add_cube("Box")
    scene.collection.objects.unlink(cube)
    src.objects.link(cube)
    places = [(0, 0, 0), (10, 0, 0), (0, 20, 5)]
    for i, p in enumerate(places):
        e = bpy.data.objects.new(f"Inst{i}", None)
        e.instance_type = "COLLECTION"
        e.instance_collection = src
        e.location = p
        scene.collection.objects.link(e)
    bpy.data.objects["Inst2"].rotation_euler = (0, 0, math.pi / 4)
    stats = {}
    sd = ex.extract_scene(dg_viewport(), stats=stats)
    assert stats["triangulations"] == 1
    assert sd.mesh.triangle_count == 36
    assert sorted(sd.mesh.object_names) == ["Inst0/Box", "Inst1/Box", "Inst2/Box"]
    for i, p in enumerate(places):
        t = tris_of(sd, f"Inst{i}/Box").reshape(-1, 3)
        np.testing.assert_allclose(t.mean(0), p, atol=1e-5)
    t = tris_of(sd, "Inst2/Box").reshape(-1, 3)      # rotated 45 degrees about Z
    np.testing.assert_allclose(t[:, 0].max(), math.sqrt(2), atol=1e-5)


def test_geometry_nodes_instances_on_points(ex, scene):
    cube = add_cube("Box")
    cube.location = (0, 0, -50)          # the instance is the object's geometry only
    host = bpy.data.objects.new("Host", bpy.data.meshes.new("HostMesh"))
    scene.collection.objects.link(host)
    ng = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = ng.nodes, ng.links
    gout = nodes.new("NodeGroupOutput")
    nodes.new("NodeGroupInput")
    line = nodes.new("GeometryNodeMeshLine")
    line.inputs["Count"].default_value = 4
    line.inputs["Offset"].default_value = (3, 0, 0)
    info = nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = cube
    iop = nodes.new("GeometryNodeInstanceOnPoints")
    links.new(line.outputs["Mesh"], iop.inputs["Points"])
    links.new(info.outputs["Geometry"], iop.inputs["Instance"])
    links.new(iop.outputs["Instances"], gout.inputs[0])
    host.modifiers.new("GN", "NODES").node_group = ng
    stats = {}
    sd = ex.extract_scene(dg_viewport(), stats=stats)
    assert sd.mesh.triangle_count == 12 * 5           # 4 instances + the original Box
    # Box, Host's own (empty) mesh and the instanced geometry, once for 4 instances
    assert stats["triangulations"] == 3
    assert sorted(sd.mesh.object_names) == ["Box"] + ["Host/Cube"] * 4
    centers = np.sort(sd.mesh.triangles.reshape(-1, 12 * 3, 3).mean(1), axis=0)
    np.testing.assert_allclose(centers[:, 2], [-50, 0, 0, 0, 0], atol=1e-5)
    np.testing.assert_allclose(np.sort(centers[1:, 0]), [0, 3, 6, 9], atol=1e-5)


def test_text_and_curve_are_not_counted_twice(ex, scene):
    bpy.ops.object.text_add()
    text = bpy.context.object
    dg = dg_viewport()
    ev = text.evaluated_get(dg)
    me = ev.to_mesh()
    me.calc_loop_triangles()
    expected = len(me.loop_triangles)
    ev.to_mesh_clear()
    assert expected > 0
    stats = {}
    sd = ex.extract_scene(dg, stats=stats)
    assert sd.mesh.triangle_count == expected
    assert stats["to_mesh"] == 0          # came as the text's MESH instance
    np.testing.assert_allclose(sd.mesh.corner_normals[:, :, 2], 1, atol=1e-6)  # flat, +Z


def test_to_mesh_fallback(ex, scene, monkeypatch):
    """If a text object yielded no MESH instance, its mesh comes from to_mesh()."""
    bpy.ops.object.text_add(location=(2, 0, 0))
    normal = ex.extract_scene(dg_viewport())
    visit = ex._Extraction.visit

    def drop_mesh_instances(self, inst):
        if not (inst.is_instance and inst.object.type == "MESH"):
            visit(self, inst)

    monkeypatch.setattr(ex._Extraction, "visit", drop_mesh_instances)
    stats = {}
    sd = ex.extract_scene(dg_viewport(), stats=stats)
    assert stats["to_mesh"] == 1
    assert sd.mesh.object_names == normal.mesh.object_names == ["Text"]
    np.testing.assert_allclose(sd.mesh.triangles, normal.mesh.triangles, atol=1e-6)


@pytest.mark.parametrize("mode", ["instance", "object"])
def test_mirrored_geometric_normal_follows_shading_normal(ex, scene, mode):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8)
    sphere = bpy.context.object
    bpy.ops.object.shade_smooth()
    if mode == "object":
        sphere.scale = (-1, 2, 1)
        sphere.rotation_euler = (0.3, 0.5, 0.7)
    else:
        src = bpy.data.collections.new("Src")
        scene.collection.objects.unlink(sphere)
        src.objects.link(sphere)
        e = bpy.data.objects.new("Mirror", None)
        e.instance_type = "COLLECTION"
        e.instance_collection = src
        e.scale = (1, 1, -3)
        scene.collection.objects.link(e)
    sd = ex.extract_scene(dg_viewport())
    assert sd.mesh.triangle_count > 0
    g = geometric_normals(sd.mesh.triangles.astype(np.float64))
    s = sd.mesh.corner_normals.mean(axis=1)
    assert (np.einsum("ij,ij->i", g, s) > 0).all()
    np.testing.assert_allclose(np.linalg.norm(sd.mesh.corner_normals, axis=2), 1, atol=1e-5)
    # outward: normals point away from the centre
    c = sd.mesh.triangles.mean(axis=1)
    assert (np.einsum("ij,ij->i", g, c) > 0).all()


def test_flat_normals_follow_nonuniform_scale(ex, scene):
    cube = add_cube()
    cube.scale = (1, 3, -0.5)
    cube.rotation_euler = (0.4, 0.1, 1.0)
    sd = ex.extract_scene(dg_viewport())
    g = geometric_normals(sd.mesh.triangles.astype(np.float64))
    for k in range(3):
        np.testing.assert_allclose(sd.mesh.corner_normals[:, k], g, atol=1e-5)


def test_smooth_and_flat_shading(ex, scene):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=1)
    sphere = bpy.context.object
    bpy.ops.object.shade_flat()
    flat = ex.extract_scene(dg_viewport()).mesh
    g = geometric_normals(flat.triangles.astype(np.float64))
    for k in range(3):
        np.testing.assert_allclose(flat.corner_normals[:, k], g, atol=1e-4)
    bpy.ops.object.shade_smooth()
    smooth = ex.extract_scene(dg_viewport()).mesh
    assert smooth.triangle_count == flat.triangle_count
    p = smooth.triangles / np.linalg.norm(smooth.triangles, axis=2, keepdims=True)
    # vertex normals ~ positions (Blender weights face normals by corner angles)
    np.testing.assert_allclose(smooth.corner_normals, p, atol=0.02)
    spread = np.linalg.norm(smooth.corner_normals[:, 0] - smooth.corner_normals[:, 1], axis=1)
    assert spread.max() > 0.1                                     # corners differ
    assert sphere.name in smooth.object_names


# ------------------------------------------------------------------------ materials

def test_mirror_materials(ex, scene):
    # Roughness-0 metals and glossy BSDFs are perfect mirrors; anything rougher or
    # partly metallic stays diffuse; a scene without mirrors reports none.
    cases = [("metal", "Principled BSDF", dict(Metallic=1.0, Roughness=0.0,
                                                **{"Base Color": (0.9, 0.8, 0.7, 1)}),
              (0.9, 0.8, 0.7)),
             ("glossy", "Glossy", dict(Roughness=0.0, Color=(0.5, 0.6, 0.7, 1)), (0.5, 0.6, 0.7)),
             ("half", "Principled BSDF", dict(Metallic=0.5, Roughness=0.0), None),
             ("rough", "Principled BSDF", dict(Metallic=1.0, Roughness=0.3), None)]
    obs = []
    for i, (name, kind, inputs, _) in enumerate(cases):
        ob = add_cube(name, location=(3 * i, 0, 0))
        assign(ob, material(name, kind, **inputs)[0])
        obs.append(ob)
    sd = extract_render(ex, scene)
    mats = sd.materials
    for name, _, _, mirror in cases:
        m = mats.names.index(name)
        if mirror is None:
            assert not mats.mirror[m].any() and mats.albedo[m].any()
        else:
            assert np.allclose(mats.mirror[m], mirror) and not mats.albedo[m].any()
    for ob in obs[:2]:
        bpy.data.objects.remove(ob)
    assert extract_render(ex, scene).materials.mirror is None


def test_materials(ex, scene):
    principled, _ = material("Principled", **{"Base Color": (0.2, 0.4, 0.6, 1)})
    diffuse, _ = material("Diffuse", "Diffuse", Color=(0.1, 0.7, 0.3, 1))
    emit, _ = material("Lamp", "Emission", Color=(1, 0.5, 0.25, 1), Strength=4.0)
    glow, _ = material("Glow", **{"Base Color": (0.5, 0.5, 0.5, 1),
                                  "Emission Color": (0.2, 1.0, 0.0, 1),
                                  "Emission Strength": 2.5})
    a = add_cube("A")
    assign(a, principled, diffuse)
    a.data.polygons.foreach_set("material_index", np.array([0, 1, 1, 0, 0, 0], np.int32))
    b = add_cube("B", (5, 0, 0))
    assign(b, emit)
    c = add_cube("C", (10, 0, 0))
    assign(c, glow)
    add_cube("D", (15, 0, 0))                          # no material: default grey
    sd = ex.extract_scene(dg_viewport())
    mats = sd.materials
    assert mats.albedo.dtype == np.float32 and mats.emission.dtype == np.float32
    by = {n: i for i, n in enumerate(mats.names)}
    assert set(by) == {"Principled", "Diffuse", "Lamp", "Glow", ex.DEFAULT_MATERIAL_NAME}
    np.testing.assert_allclose(mats.albedo[by["Principled"]], (0.2, 0.4, 0.6), atol=1e-6)
    np.testing.assert_allclose(mats.emission[by["Principled"]], 0, atol=1e-6)
    np.testing.assert_allclose(mats.albedo[by["Diffuse"]], (0.1, 0.7, 0.3), atol=1e-6)
    np.testing.assert_allclose(mats.albedo[by["Lamp"]], 0, atol=1e-6)
    np.testing.assert_allclose(mats.emission[by["Lamp"]], (4, 2, 1), atol=1e-6)
    np.testing.assert_allclose(mats.albedo[by["Glow"]], 0.5, atol=1e-6)
    np.testing.assert_allclose(mats.emission[by["Glow"]], (0.5, 2.5, 0), atol=1e-6)
    np.testing.assert_allclose(mats.albedo[by[ex.DEFAULT_MATERIAL_NAME]], 0.8, atol=1e-6)
    np.testing.assert_allclose(mats.emission[by[ex.DEFAULT_MATERIAL_NAME]], 0, atol=1e-6)
    # per-triangle mapping through the slots: faces 1 and 2 (4 triangles) use slot 1
    mi = sd.mesh.material_index[sd.mesh.object_index == sd.mesh.object_names.index("A")]
    assert (mi == by["Diffuse"]).sum() == 4 and (mi == by["Principled"]).sum() == 8
    for name, m in (("B", "Lamp"), ("C", "Glow"), ("D", ex.DEFAULT_MATERIAL_NAME)):
        mi = sd.mesh.material_index[sd.mesh.object_index == sd.mesh.object_names.index(name)]
        assert (mi == by[m]).all()
    assert sd.warnings == []


def test_mix_and_add_shaders(ex, scene):
    mat = bpy.data.materials.new("Mixed")
    tree = mat.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    for n in list(tree.nodes):
        if n != out:
            tree.nodes.remove(n)
    diff = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diff.inputs["Color"].default_value = (0.8, 0.4, 0.0, 1)
    em = tree.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (1, 1, 1, 1)
    em.inputs["Strength"].default_value = 10
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.25
    tree.links.new(diff.outputs[0], mix.inputs[1])
    tree.links.new(em.outputs[0], mix.inputs[2])
    em2 = tree.nodes.new("ShaderNodeEmission")
    em2.inputs["Color"].default_value = (0, 1, 0, 1)
    em2.inputs["Strength"].default_value = 2
    add = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(mix.outputs[0], add.inputs[0])
    tree.links.new(em2.outputs[0], add.inputs[1])
    tree.links.new(add.outputs[0], out.inputs["Surface"])
    assign(add_cube(), mat)
    sd = ex.extract_scene(dg_viewport())
    i = sd.materials.names.index("Mixed")
    np.testing.assert_allclose(sd.materials.albedo[i], (0.6, 0.3, 0.0), atol=1e-6)
    np.testing.assert_allclose(sd.materials.emission[i], (2.5, 4.5, 2.5), atol=1e-6)


def test_textured_base_color_uses_the_image_average_and_warns(ex, scene):
    img = bpy.data.images.new("Checker", 2, 2)         # byte buffer, sRGB
    img.pixels.foreach_set(np.array([1, 0, 0, 1, 0, 0, 1, 1] * 2, np.float32))
    mat, bsdf = material("Textured", **{"Base Color": (0.1, 0.1, 0.1, 1)})
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    noisy, bsdf2 = material("Noisy")
    noisy.diffuse_color = (0.3, 0.2, 0.1, 1)
    noise = noisy.node_tree.nodes.new("ShaderNodeTexNoise")
    noisy.node_tree.links.new(noise.outputs["Color"], bsdf2.inputs["Base Color"])
    assign(add_cube("A"), mat)
    assign(add_cube("B", (4, 0, 0)), noisy)
    assign(add_cube("C", (8, 0, 0)), noisy)          # same material: one warning
    sd = ex.extract_scene(dg_viewport())
    m = sd.materials
    np.testing.assert_allclose(m.albedo[m.names.index("Textured")], (0.5, 0, 0.5), atol=1e-6)
    np.testing.assert_allclose(m.albedo[m.names.index("Noisy")], (0.3, 0.2, 0.1), atol=1e-6)
    assert len(sd.warnings) == 2
    assert any("Textured" in w and "Checker" in w for w in sd.warnings)
    assert any("Noisy" in w for w in sd.warnings)


# ----------------------------------------------------------------------- visibility

def _visibility_scene(scene):
    add_cube("Visible")
    add_cube("Hidden", (3, 0, 0)).hide_render = True
    coll = bpy.data.collections.new("NoRender")
    scene.collection.children.link(coll)
    coll.hide_render = True
    c = add_cube("InNoRender", (6, 0, 0))
    scene.collection.objects.unlink(c)
    coll.objects.link(c)
    excl = bpy.data.collections.new("Excluded")
    scene.collection.children.link(excl)
    c = add_cube("InExcluded", (9, 0, 0))
    scene.collection.objects.unlink(c)
    excl.objects.link(c)
    bpy.context.view_layer.layer_collection.children["Excluded"].exclude = True
    hold = bpy.data.collections.new("Hold")
    scene.collection.children.link(hold)
    c = add_cube("InHoldout", (12, 0, 0))
    scene.collection.objects.unlink(c)
    hold.objects.link(c)
    bpy.context.view_layer.layer_collection.children["Hold"].holdout = True
    add_cube("ObjHoldout", (15, 0, 0)).is_holdout = True
    for name, hidden in (("Lamp", False), ("HiddenLamp", True)):
        ob = bpy.data.objects.new(name, bpy.data.lights.new(name, "POINT"))
        ob.hide_render = hidden
        scene.collection.objects.link(ob)


@pytest.mark.parametrize("depsgraph", ["viewport", "render"])
def test_render_visibility_and_holdout(ex, scene, depsgraph):
    _visibility_scene(scene)
    sd = ex.extract_scene(dg_viewport()) if depsgraph == "viewport" else \
        extract_render(ex, scene)
    names = sd.mesh.object_names
    assert sorted(names) == ["InHoldout", "ObjHoldout", "Visible"]
    hold = dict(zip(names, sd.mesh.object_holdout))
    assert hold == {"Visible": False, "InHoldout": True, "ObjHoldout": True}
    assert sd.mesh.object_holdout.dtype == bool
    assert len(sd.lights) == 1


def test_hidden_in_instanced_collection_and_instancer(ex, scene):
    src = bpy.data.collections.new("Src")
    for name, hidden in (("Shown", False), ("Gone", True)):
        c = add_cube(name)
        c.hide_render = hidden
        scene.collection.objects.unlink(c)
        src.objects.link(c)
    for name, hidden in (("I0", False), ("I1", True)):
        e = bpy.data.objects.new(name, None)
        e.instance_type = "COLLECTION"
        e.instance_collection = src
        e.hide_render = hidden
        scene.collection.objects.link(e)
    for sd in (ex.extract_scene(dg_viewport()), extract_render(ex, scene)):
        assert sd.mesh.object_names == ["I0/Shown"]


def test_vertex_instancer_children_hidden_like_render(ex, scene):
    bpy.ops.mesh.primitive_plane_add(size=2)
    plane = bpy.context.object
    plane.instance_type = "VERTS"
    plane.show_instancer_for_render = False
    child = add_cube("Child", size=0.2)
    child.parent = plane
    for sd in (ex.extract_scene(dg_viewport()), extract_render(ex, scene)):
        assert sd.mesh.object_names == ["Plane/Child"] * 4
        assert sd.mesh.triangle_count == 48


# --------------------------------------------------------------------------- lights

def add_light(scene, name, kind, location=(0, 0, 0), rotation=(0, 0, 0), scale=(1, 1, 1),
              **props):
    data = bpy.data.lights.new(name, kind)
    for k, v in props.items():
        setattr(data, k, v)
    ob = bpy.data.objects.new(name, data)
    ob.location, ob.rotation_euler, ob.scale = location, rotation, scale
    scene.collection.objects.link(ob)
    return ob


def test_lights(ex, scene):
    add_light(scene, "P", "POINT", (1, 2, 3), energy=100, exposure=1.0,
              shadow_soft_size=0.25, color=(1, 0.5, 0.5))
    warm = add_light(scene, "T", "POINT", (0, 0, 1), energy=10, use_temperature=True,
                     temperature=3000)
    add_light(scene, "S", "SPOT", (0, 0, 5), rotation=(math.pi / 2, 0, 0), energy=50,
              spot_size=math.radians(60), spot_blend=0.3, shadow_soft_size=0.1)
    add_light(scene, "R", "AREA", (0, 0, 4), rotation=(0, 0, math.pi / 2), scale=(2, 3, 1),
              energy=200, shape="RECTANGLE", size=1.0, size_y=0.5, exposure=-1)
    add_light(scene, "Q", "AREA", energy=1, shape="SQUARE", size=2.0, size_y=7.0)
    add_light(scene, "E", "AREA", energy=1, shape="ELLIPSE", size=2.0, size_y=0.5)
    add_light(scene, "Dk", "AREA", energy=1, shape="DISK", size=3.0, size_y=7.0)
    add_light(scene, "Sun", "SUN", rotation=(math.pi / 4, 0, 0), energy=3, exposure=2,
              angle=math.radians(1))
    add_light(scene, "Portal", "AREA").data.cycles.is_portal = True
    baked = add_light(scene, "Baked", "POINT", energy=7)
    baked["irad_baked"] = 1
    sd = ex.extract_scene(dg_viewport())
    L = sd.lights
    assert len(L) == 8
    pts = [l for l in L if type(l).__name__ == "PointLight"]
    p = next(l for l in pts if l.power == pytest.approx(200))
    np.testing.assert_allclose(p.position, (1, 2, 3), atol=1e-6)
    np.testing.assert_allclose(p.color, (1, 0.5, 0.5), atol=1e-6)
    assert p.radius == pytest.approx(0.25)
    t = next(l for l in pts if l.power == pytest.approx(10))
    np.testing.assert_allclose(t.color, tuple(warm.data.temperature_color), atol=1e-6)
    assert t.color[0] > t.color[2]                      # 3000 K is warm
    s = next(l for l in L if type(l).__name__ == "SpotLight")
    np.testing.assert_allclose(s.direction, (0, 1, 0), atol=1e-6)   # -Z rotated by +90 X
    assert (s.power, s.radius) == (pytest.approx(50), pytest.approx(0.1))
    assert (s.spot_size, s.spot_blend) == (pytest.approx(math.radians(60)), pytest.approx(0.3))
    areas = {round(float(a.power), 4): a for a in L if type(a).__name__ == "AreaLight"}
    r = areas[100.0]                                    # 200 * 2**-1
    assert r.shape == "RECTANGLE"
    np.testing.assert_allclose(r.center, (0, 0, 4), atol=1e-6)
    np.testing.assert_allclose(r.axis_u, (0, 1, 0), atol=1e-6)     # X*2 scale*1/2, rotated
    np.testing.assert_allclose(r.axis_v, (-0.75, 0, 0), atol=1e-6)  # Y*3 scale*0.5/2
    np.testing.assert_allclose(r.normal, (0, 0, -1), atol=1e-6)
    unit = [a for a in L if type(a).__name__ == "AreaLight" and a.power == pytest.approx(1)]
    got = sorted((a.shape, round(float(np.linalg.norm(a.axis_u)), 4),
                  round(float(np.linalg.norm(a.axis_v)), 4)) for a in unit)
    assert got == [("ELLIPSE", 1.0, 0.25), ("ELLIPSE", 1.5, 1.5), ("RECTANGLE", 1.0, 1.0)]
    sun = next(l for l in L if type(l).__name__ == "SunLight")
    assert sun.strength == pytest.approx(12)
    assert sun.angle == pytest.approx(math.radians(1))
    h = math.sqrt(0.5)
    np.testing.assert_allclose(sun.direction, (0, -h, h), atol=1e-6)   # +Z rotated 45 X
    sd = ex.extract_scene(dg_viewport(), include_baked=True)
    assert len(sd.lights) == 9


def test_unnormalized_area_light_power_is_per_area(ex, scene):
    add_light(scene, "R", "AREA", scale=(2, 1, 1), energy=10, shape="RECTANGLE",
              size=1.0, size_y=3.0, normalize=False)
    (light,) = ex.extract_scene(dg_viewport()).lights
    assert light.power == pytest.approx(10 * 2 * 3)


def test_instanced_lights(ex, scene):
    src = bpy.data.collections.new("Src")
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.location = (0, 0, 2)
    src.objects.link(lamp)
    for i in range(3):
        e = bpy.data.objects.new(f"I{i}", None)
        e.instance_type = "COLLECTION"
        e.instance_collection = src
        e.location = (i * 10, 0, 0)
        scene.collection.objects.link(e)
    sd = ex.extract_scene(dg_viewport())
    got = sorted(tuple(np.round(l.position, 5)) for l in sd.lights)
    assert got == [(0, 0, 2), (10, 0, 2), (20, 0, 2)]


# --------------------------------------------------------------------------- camera

def test_perspective_camera(ex, scene):
    cam = add_camera(scene, lens=35, sensor_width=32, sensor_height=20, sensor_fit="VERTICAL",
                     shift_x=0.1, shift_y=-0.2, clip_start=0.5, clip_end=300)
    cam.location = (1, 2, 3)
    cam.rotation_euler = (1.0, 0.2, 0.3)
    cam.scale = (2, 2, 2)
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = 1921, 1081, 50
    r.pixel_aspect_x, r.pixel_aspect_y = 1.0, 2.0
    c = ex.extract_scene(dg_viewport()).camera
    assert c.projection == "PERSP"
    assert (c.lens, c.sensor_width, c.sensor_height, c.sensor_fit) == (35, 32, 20, "VERTICAL")
    assert (c.shift_x, c.shift_y) == (pytest.approx(0.1), pytest.approx(-0.2))
    assert (c.clip_start, c.clip_end) == (pytest.approx(0.5), pytest.approx(300))
    assert (c.width, c.height) == (960, 540)
    assert (c.pixel_aspect_x, c.pixel_aspect_y) == (1.0, 2.0)
    assert c.matrix_world.dtype == np.float64 and c.matrix_world.shape == (4, 4)
    np.testing.assert_allclose(c.matrix_world[:3, 3], (1, 2, 3), atol=1e-6)
    rot = c.matrix_world[:3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-6)     # scale removed
    expected = np.array(cam.matrix_world.normalized(), np.float64)
    np.testing.assert_allclose(c.matrix_world, expected, atol=1e-6)


def test_ortho_and_panoramic_cameras(ex, scene):
    add_camera(scene, type="ORTHO", ortho_scale=7.5)
    c = ex.extract_scene(dg_viewport()).camera
    assert c.projection == "ORTHO" and c.ortho_scale == pytest.approx(7.5)
    scene.camera.data.type = "PANO"
    sd = ex.extract_scene(dg_viewport())
    assert sd.camera.projection == "PERSP"
    assert any("PANO" in w for w in sd.warnings)


# ---------------------------------------------------------------------- world, empty

def test_world_color(ex, scene):
    world = bpy.data.worlds.new("W")
    scene.world = world
    bg = next(n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeBackground")
    bg.inputs["Color"].default_value = (0.2, 0.3, 0.4, 1)
    bg.inputs["Strength"].default_value = 2.0
    np.testing.assert_allclose(ex.extract_scene(dg_viewport()).world_radiance,
                               (0.4, 0.6, 0.8), atol=1e-6)
    # an image-textured background: the image's (solid-angle weighted) average + a warning
    img = bpy.data.images.new("Sky", 4, 2, float_buffer=True)
    img.pixels.foreach_set(np.full(4 * 2 * 4, 0.5, np.float32))
    env = world.node_tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = img
    world.node_tree.links.new(env.outputs["Color"], bg.inputs["Color"])
    sd = ex.extract_scene(dg_viewport())
    np.testing.assert_allclose(sd.world_radiance, (1, 1, 1), atol=1e-6)
    assert len(sd.warnings) == 1 and "Sky" in sd.warnings[0]


def test_empty_scene(ex, scene):
    assert scene.world is None and scene.camera is None
    sd = ex.extract_scene(dg_viewport())
    assert sd.camera is None
    np.testing.assert_array_equal(sd.world_radiance, (0, 0, 0))
    assert sd.world_radiance.shape == (3,)
    m = sd.mesh
    assert m.triangles.shape == (0, 3, 3) and m.triangles.dtype == np.float32
    assert m.corner_normals.shape == (0, 3, 3) and m.corner_normals.dtype == np.float32
    assert m.material_index.shape == (0,) and m.material_index.dtype == np.int32
    assert m.object_index.shape == (0,) and m.object_index.dtype == np.int32
    assert m.object_names == [] and m.object_holdout.shape == (0,)
    assert sd.materials.albedo.shape == (0, 3) and sd.materials.emission.shape == (0, 3)
    assert sd.lights == [] and sd.warnings == []


# ---------------------------------------------------------------------- performance

def test_one_million_triangles_extract_fast(ex, scene):
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=708, y_subdivisions=708, size=2)
    grid = bpy.context.object
    grid.rotation_euler = (0.1, 0.2, 0.3)
    grid.scale = (1, -2, 1)                 # the slowest path: non-uniform mirror
    dg = dg_viewport()
    t0 = time.perf_counter()
    sd = ex.extract_scene(dg)
    dt = time.perf_counter() - t0
    assert sd.mesh.triangle_count == 708 * 708 * 2     # 5.0: subdivisions = quads
    print(f"\nextract_scene: {sd.mesh.triangle_count} triangles in {dt:.3f} s")
    assert dt < 2.0
