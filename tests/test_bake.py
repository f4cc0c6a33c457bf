"""Baked bounce lights: the disk-light maths, and Cycles renders of a bake against
full global illumination on the Cornell box."""
import bpy
import numpy as np
import pytest

import synthetic
from benchmarks import metrics, reference, scenes

RESOLUTION = 48
PARTICLES = 2400          # ~4100 VPLs in the Cornell box with a point light


@pytest.fixture
def core(addon):
    return addon.irad_addon


# ------------------------------------------------------------------------------ maths

def test_lights_face_along_the_vpl_normal(core):
    bm = core.bake_math
    rng = np.random.default_rng(3)
    normals = rng.normal(size=(200, 3))
    normals = np.concatenate([normals, [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 0, 0.999999]]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    q = bm.quaternion_down_to(normals)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    assert np.allclose(bm.rotate_down_axis(q), normals, atol=1e-9)


def test_light_power_is_the_vpl_flux(core):
    bm = core.bake_math
    flux = np.array([[0.2, 0.1, 0.05], [0.0, 0.0, 0.0], [1.0, 3.0, 2.0], [np.nan, 1.0, 0.5]])
    energy, color = bm.split_power(flux)
    assert np.allclose(energy[:, None] * color, np.nan_to_num(flux))
    assert np.allclose(color.max(1)[energy > 0], 1.0)
    lights = bm.disk_lights(np.zeros((4, 3)), np.tile([0, 0, 1.0], (4, 1)), flux, 0.1, 1.0)
    assert lights.count == 3                       # the black VPL makes no light
    assert np.allclose(lights.size, 0.2)           # Blender's disk size is a diameter


def test_disks_are_fitted_off_nearby_walls(core):
    """A disk crossing a wall would light it from zero distance: slide and shrink it."""
    bm = core.bake_math
    tracer = core.rays.RayTracer(synthetic.closed_box(2))          # the box [-1, 1]^3
    centre = np.array([[0.0, 0.0, -0.999], [0.95, 0.0, -0.999], [0.98, 0.98, -0.999]])
    normal = np.tile([0.0, 0.0, 1.0], (3, 1))                      # on the floor
    radius = np.full(3, 0.2)
    fitted, r = bm.fit_disks(tracer, centre, normal, radius, 1e-4)
    assert np.allclose(fitted[0], centre[0]) and r[0] == pytest.approx(0.2)
    # Every disk now lies inside the box, in its own plane.
    assert np.all(np.abs(fitted[:, :2]) + r[:, None] <= 1.0 + 1e-6)
    assert np.allclose(fitted[:, 2], -0.999)
    assert fitted[1, 0] < 0.95 and r[1] > 0.15       # slid away from the wall x = 1
    assert r[2] > 0.05                               # the corner keeps a usable disk


def test_clusters_keep_the_total_flux(core):
    bm, tree = core.bake_math, core.light_tree
    rng = np.random.default_rng(0)
    position = rng.uniform(-1, 1, (500, 3))
    position[:, 2] = -1.0
    normal = np.tile([0.0, 0.0, 1.0], (500, 1))
    flux = rng.uniform(0.0, 0.1, (500, 3))
    clusters = tree.cluster_by_budget(position, normal, flux, 16)
    lights = bm.clustered_disk_lights(position, normal, flux, clusters, 0.05, 2.0)
    assert lights.count <= 16
    assert np.allclose((lights.energy[:, None] * lights.color).sum(0), flux.sum(0))
    assert 0 < lights.relative_error < 1
    assert np.all(lights.size >= 0.1)              # never below the clamp distance


def test_animation_frames_are_padded_with_dark_lights(core):
    bm = core.bake_math
    one = bm.disk_lights(np.zeros((2, 3)), np.tile([0, 0, 1.0], (2, 1)), np.ones((2, 3)),
                         0.1, 1.0)
    three = bm.disk_lights(np.zeros((3, 3)), np.tile([0, 0, 1.0], (3, 1)),
                           np.full((3, 3), 2.0), 0.1, 1.0)
    padded = bm.pad_frames([one, three])
    assert padded["energy"].shape == (2, 3)
    assert np.allclose(padded["energy"], [[1, 1, 0], [2, 2, 2]])
    assert np.all(padded["size"] > 0)


# ---------------------------------------------------------------------- Cycles renders

def cornell(budget):
    scene = scenes.cornell_box("POINT", RESOLUTION)
    scene["irad_scene_key"] = "cornell_box:POINT:bake-test"   # our own cache entries
    scene.irad.particles = PARTICLES
    scene.irad.light_budget = budget
    return scene


def render_direct_only(scene, samples):
    """Cycles with every bounce off: the scene's own lights and the baked lights, direct."""
    reference.configure_cycles(scene, samples, direct_only=True)
    return reference.render_image(scene)


@pytest.mark.parametrize("budget, samples, tolerance", [(4096, 128, 0.05), (64, 64, 0.1)])
def test_baked_lights_reproduce_global_illumination_in_cycles(scene, budget, samples,
                                                              tolerance):
    scene = cornell(budget)
    # References first: rendered after the bake they would include the baked lights.
    full_gi = reference.cycles_reference(scene, 256)
    direct = reference.cycles_reference(scene, 64, direct_only=True)
    # Close to, but not above, 4096 VPLs (the count per particle depends on the tracer).
    assert bpy.ops.irad.compute_vpls() == {'FINISHED'}
    scene.irad.particles = int(PARTICLES * 4050 / max(scene.irad.bake_vpl_count, 4050))
    assert bpy.ops.irad.bake_lights() == {'FINISHED'}
    vpl_count = scene.irad.bake_vpl_count
    assert 3800 <= vpl_count <= 4096
    expected_lights = vpl_count if budget >= vpl_count else budget
    assert scene.irad.bake_light_count == expected_lights
    image = render_direct_only(scene, samples)
    error = metrics.relmse(image, full_gi)
    print(f"budget {budget}: {vpl_count} VPLs -> {expected_lights} lights, relMSE {error:.4f}, "
          f"bias {metrics.relative_bias(image, full_gi):+.3f}, without the bake "
          f"{metrics.relmse(direct, full_gi):.4f}")
    assert error < tolerance
    assert abs(metrics.relative_bias(image, full_gi)) < 0.06
    # The bake carries the bounce light: without it the image is far off.
    assert metrics.relmse(direct, full_gi) > 4 * error
