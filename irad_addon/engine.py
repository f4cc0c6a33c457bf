"""The INSTANT_RADIOSITY RenderEngine: Blender glue around render.render_frame."""
import traceback

import bpy
import numpy as np

from . import extract, preferences, render, variants
from .frame import InvalidScene
from .rays import RayTracerCache
from .temporal import PathWindow

# Extra passes we always write; Depth, Normal and Albedo are added beside them.
PASSES = [(name, channels) for name, channels in render.PASS_CHANNELS.items()
          if name != "Combined"]
_CHANNEL_IDS = {1: "Z", 3: "RGB", 4: "RGBA"}


def render_settings(scene):
    irad = scene.irad
    seed = irad.seed + (scene.frame_current if irad.use_animated_seed else 0)
    return render.RenderSettings(
        particles=irad.particles, max_bounces=irad.max_bounces, clamp=irad.clamp,
        aa_samples=irad.aa_samples, coverage_samples=irad.coverage_samples,
        interleave=irad.interleave,
        bias_compensation=irad.bias_compensation,
        shadow_ray_budget=irad.shadow_ray_budget, use_lightcuts=irad.use_lightcuts,
        lightcut_error=irad.lightcut_error, max_cut=irad.max_cut,
        light_samples=irad.light_samples, seed=seed,
        variant=irad.variant, sequence=irad.sequence, temporal_reuse=irad.temporal_reuse,
        temporal_frames=irad.temporal_frames,
        film_transparent=scene.render.film_transparent)


class InstantRadiosityEngine(bpy.types.RenderEngine):
    bl_idname = "INSTANT_RADIOSITY"
    bl_label = "Instant Radiosity"
    bl_use_preview = False
    bl_use_postprocess = True

    # One BVH cache per engine class: frames of an animation with unchanged geometry
    # reuse the Embree scene instead of rebuilding it.
    tracer_cache = RayTracerCache()
    # Camera fly-throughs reuse the VPLs while lights and geometry stay the same, or
    # gather the paths of the last few frames (temporal.PathWindow).
    path_window = PathWindow()
    # What the last render wrote (pass names, stats): for scripts, the demo and tests.
    last_render = {}

    # What incremental IR keeps from frame to frame, and what Auto compares the frames
    # by. Class-level: Blender makes a new engine for every frame of an animation.
    variant_state = variants.VariantState()

    def update_render_passes(self, scene=None, renderlayer=None):
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", 'COLOR')
        for name, channels in PASSES:
            kind = 'VALUE' if channels == 1 else ('VECTOR' if name == "Normal" else 'COLOR')
            self.register_pass(scene, renderlayer, name, channels, _CHANNEL_IDS[channels], kind)

    def render(self, depsgraph):
        scene = depsgraph.scene
        width, height = self.resolution_x, self.resolution_y
        try:
            data = extract.extract_scene(depsgraph)
            for message in data.warnings:
                self.report({'WARNING'}, message)
            result = render.render_frame(
                data, render_settings(scene), cancel=self.test_break,
                progress=self._progress, frame_number=scene.frame_current,
                shot=(bpy.data.filepath, scene.name), **self._caches())
        except render.Cancelled:
            return
        except InvalidScene as error:
            self._fail(f"Instant Radiosity: {error}", width, height, depsgraph)
            return
        except Exception as error:   # a bug of ours: say so plainly, keep the trace in the console
            traceback.print_exc()
            self._fail(f"Instant Radiosity failed: {type(error).__name__}: {error}",
                       width, height, depsgraph)
            return
        for message in result.warnings:
            self.report({'WARNING'}, message)
        written = self._write(result.passes, depsgraph)
        type(self).last_render = {"passes": written, "stats": result.stats}
        stats = result.stats
        self.update_stats("", f"{stats['variant_reason']} | VPLs {stats['vpls']} | shadow "
                              f"rays per pixel sample {stats.get('shadow_rays_per_point', 0):.0f}"
                              f" | {stats['time']:.2f} s")

    def _caches(self):
        """The BVH, VPL and variant caches, unless the user switched caching off."""
        if not preferences.use_cache():
            return {}
        return {"tracer_cache": self.tracer_cache, "path_window": self.path_window,
                "variant_state": self.variant_state}

    def _fail(self, message, width, height, depsgraph):
        self.report({'ERROR'}, message)
        self._write({"Combined": np.zeros((height, width, 4), np.float32)}, depsgraph)

    def _progress(self, fraction, message):
        self.update_progress(fraction)
        self.update_stats("", message)

    def _write(self, passes, depsgraph):
        view_layer = depsgraph.view_layer
        layer_name = view_layer.name
        # Depth and Normal already exist when the view layer enables Blender's own.
        builtin = {"Depth": view_layer.use_pass_z, "Normal": view_layer.use_pass_normal}
        for name, channels in PASSES:
            if name in passes and not builtin.get(name, False):
                self.add_pass(name, channels, _CHANNEL_IDS[channels], layer=layer_name)
        image = next(iter(passes.values()))
        height, width = image.shape[:2]
        result = self.begin_result(0, 0, width, height, layer=layer_name)
        written = []
        for render_pass in result.layers[0].passes:
            data = passes.get(render_pass.name)
            if data is not None and data.shape[2] == render_pass.channels:
                # Blender stores rows bottom-up; ours are top-down.
                render_pass.rect.foreach_set(np.ascontiguousarray(data[::-1]).ravel())
                written.append(render_pass.name)
        self.end_result(result)
        return written


def register():
    bpy.utils.register_class(InstantRadiosityEngine)


def unregister():
    bpy.utils.unregister_class(InstantRadiosityEngine)
