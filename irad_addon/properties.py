"""Settings at scene.irad: what the panels show and the engine reads."""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

from . import overlay
from .render import RenderSettings

# One source of truth for defaults: the core's RenderSettings.
_DEFAULT = RenderSettings()

VARIANTS = [
    ('CLASSIC', "Classic", "Instant Radiosity (Keller 1997): particles from the lights, "
                           "a virtual point light at every diffuse bounce"),
    ('BIDIRECTIONAL', "Bidirectional", "Bidirectional Instant Radiosity (Segovia et al. 2006): "
                                       "VPLs also where the camera's paths land, resampled "
                                       "by what they bring to the image (light in another "
                                       "room)"),
    ('METROPOLIS', "Metropolis", "Metropolis Instant Radiosity (Segovia et al. 2007): VPLs "
                                 "distributed by the power they bring to the camera"),
    ('INCREMENTAL', "Incremental", "Incremental Instant Radiosity (Laine et al. 2007): VPLs "
                                   "persist across animation frames; only invalid ones are "
                                   "replaced (moving point and spot lights)"),
    ('AUTO', "Auto", "A quick pilot pass picks the variant for this scene; the choice and "
                     "why are shown in the render stats"),
]


class IRadSettings(bpy.types.PropertyGroup):
    variant: EnumProperty(name="Variant", items=VARIANTS, default='CLASSIC',
                          description="How virtual point lights are placed")
    particles: IntProperty(name="Particles", default=_DEFAULT.particles, min=1, soft_min=16,
                           soft_max=65536, max=10_000_000,
                           description="Particles shot from the lights; every diffuse bounce "
                                       "leaves a virtual point light (VPL)")
    max_bounces: IntProperty(name="Max Bounces", default=_DEFAULT.max_bounces, min=0,
                             soft_max=64, max=1024,
                             description="Most indirect bounces a particle makes; 0 renders "
                                         "direct light only")
    clamp: FloatProperty(name="Clamp", default=_DEFAULT.clamp, min=0.0, soft_max=4.0, max=100.0,
                         description="Closest distance at which a VPL lights a point, in units "
                                     "of the mean VPL spacing: hides the bright spots next to "
                                     "VPLs at the cost of darker corners; the bias shrinks as "
                                     "VPLs are added (0 disables)")
    bias_compensation: BoolProperty(
        name="Bias Compensation", default=_DEFAULT.bias_compensation,
        description="Restore the light that clamping removes near VPLs, with one extra ray "
                    "per pixel sample (Kollig & Keller 2004)")
    shadow_ray_budget: FloatProperty(
        name="Shadow Ray Budget", default=_DEFAULT.shadow_ray_budget, min=0.0, soft_min=16.0,
        soft_max=4096.0, max=1e6,
        description="About the most shadow rays a pixel sample traces to VPLs, over all "
                    "interleaved groups (each sample gathers one of Interleave x Interleave "
                    "groups and gets that share). A VPL that brings less than its share's "
                    "fraction of the unoccluded light keeps its ray with probability in "
                    "proportion, weighted by the inverse: no bias, a little noise. "
                    "0 traces every VPL's ray")
    use_lightcuts: BoolProperty(
        name="Lightcuts", default=_DEFAULT.use_lightcuts,
        description="Gather a cut of a light tree per pixel instead of every VPL (Walter et "
                    "al. 2005): cost grows slowly with the VPL count. Pays off from about "
                    "10k VPLs per pixel sample")
    lightcut_error: FloatProperty(
        name="Error", default=_DEFAULT.lightcut_error, min=0.0, soft_min=0.001, soft_max=0.1,
        max=1.0, subtype='FACTOR',
        description="Refine each pixel's cut until every cluster's error bound is below "
                    "this fraction of the pixel's estimate")
    max_cut: IntProperty(name="Max Cut", default=_DEFAULT.max_cut, min=1, soft_max=10000,
                         max=1_000_000, description="Most clusters (shadow rays) per pixel")
    aa_samples: IntProperty(name="Shading Samples", default=_DEFAULT.aa_samples, min=1,
                            soft_max=64, max=4096,
                            description="Camera samples per pixel that gather light "
                                        "(the render's cost grows with them)")
    coverage_samples: IntProperty(
        name="Edge Samples", default=_DEFAULT.coverage_samples, min=0, soft_max=64,
        max=4096, description="Camera rays per pixel for anti-aliased edges: each takes "
                              "the light gathered by a shading sample on the same surface "
                              "(no more than Shading Samples: off)")
    interleave: IntProperty(name="Interleave", default=_DEFAULT.interleave, min=1, soft_max=8,
                            max=16,
                            description="Interleaved sampling: each pixel of a k x k tile "
                                        "gathers a different VPL subset, then a filter that "
                                        "respects edges merges them (1 disables)")
    light_samples: IntProperty(name="Light Samples", default=_DEFAULT.light_samples,
                               min=1, soft_max=64, max=4096,
                               description="Shadow rays per shading sample to each area light, "
                                           "emissive mesh and the world (soft shadows)")
    sequence: EnumProperty(
        name="Sequence", default=_DEFAULT.sequence,
        items=[('HALTON', "Halton", "Scrambled Halton sequence (Keller 1997)"),
               ('HAMMERSLEY', "Hammersley", "Hammersley points: evenly spaced in the first "
                                            "dimension, Halton in the others"),
               ('JITTERED', "Jittered Hammersley", "Hammersley with the first dimension "
                                                   "jittered in its stratum (Keller 1997)")],
        description="Low-discrepancy sequence the particles are drawn from")
    temporal_reuse: BoolProperty(
        name="Reuse VPLs Across Frames", default=_DEFAULT.temporal_reuse,
        description="While lights, geometry and these settings stay the same (a camera "
                    "fly-through), render every frame with the same VPLs: faster, and no "
                    "flicker (Keller 1997)")
    temporal_frames: IntProperty(
        name="Path Frames", default=_DEFAULT.temporal_frames, min=1, soft_max=16, max=256,
        description="Classic: gather the particle paths of the last N frames. Each frame "
                    "traces new particles and keeps the paths of the N - 1 frames before: "
                    "a camera fly-through reaches N times the particles at the tracing "
                    "cost of one, and bounce light under moving lights or objects changes "
                    "smoothly, lagging up to N frames (Keller 1997). 1: this frame's paths")
    seed: IntProperty(name="Seed", default=_DEFAULT.seed, min=0,
                      description="Randomisation of the sample sequences")
    use_animated_seed: BoolProperty(name="Animated Seed", default=False,
                                    description="Use a different seed for every frame")

    # ---- Bake bounce lights (irad_addon/bake.py, operators/, panels/sidebar.py) ----
    light_budget: IntProperty(name="Light Budget", default=64, min=1, max=4096,
                              soft_min=1, soft_max=1024,
                              description="Most lights a bake creates: above it, VPLs are "
                                          "clustered with a light tree (Lightcuts) into this "
                                          "many lights. EEVEE shows at most 4096 lights")
    show_vpl_overlay: BoolProperty(name="Show VPLs", default=False,
                                   update=lambda self, context: overlay.update(self, context),
                                   description="Draw the last computed virtual point lights "
                                               "in the 3D Viewport, coloured by flux")
    bake_vpl_count: IntProperty(name="VPLs", default=0, min=0,
                                description="VPLs traced by the last compute or bake")
    bake_light_count: IntProperty(name="Lights", default=0, min=0,
                                  description="Bounce lights created by the last bake")
    bake_seconds: FloatProperty(name="Bake Time", default=0.0, min=0.0, unit='TIME_ABSOLUTE',
                                description="Seconds the last compute or bake took")
    bake_relative_error: FloatProperty(name="Estimated Error", default=0.0, min=0.0,
                                       subtype='FACTOR',
                                       description="Flux-weighted spread of the light clusters "
                                                   "relative to the scene size (0: one light "
                                                   "per VPL)")
    # ---- end of bake properties ----


def register():
    bpy.utils.register_class(IRadSettings)
    bpy.types.Scene.irad = PointerProperty(type=IRadSettings)


def unregister():
    del bpy.types.Scene.irad
    bpy.utils.unregister_class(IRadSettings)
