"""One frame, end to end: G-buffer, VPLs, direct and indirect gather, passes."""
import time
from dataclasses import dataclass, field

import numpy as np

from . import gather, geometry, interleaving, vpl
from .frame import InvalidScene, check_renderable, prepare_frame
from .gbuffer import build_gbuffer


@dataclass
class RenderSettings:
    particles: int = 2048
    max_bounces: int = 8
    clamp: float = 1.0           # VPL clamping distance in units of the mean VPL spacing
    aa_samples: int = 4
    interleave: int = 4          # k: k x k interleaved VPL subsets + discontinuity buffer
    light_samples: int = 4
    seed: int = 0
    variant: str = 'CLASSIC'
    film_transparent: bool = False


@dataclass
class RenderResult:
    passes: dict                 # name -> float32 (H, W, C), row 0 = top
    stats: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)


PASS_CHANNELS = {"Combined": 4, "IRAD Direct": 3, "IRAD Indirect": 3, "Depth": 1,
                 "Normal": 3, "Albedo": 3}


class Cancelled(Exception):
    pass


def clamp_distance(frame, vpls, clamp):
    """Minimum VPL distance: `clamp` times the mean spacing of the VPLs over the
    scene's surfaces, so the clamp (and its bias) shrinks as VPLs are added."""
    if clamp <= 0 or vpls.count == 0:
        return 0.0
    area = float(geometry.triangle_areas(frame.triangles).sum())
    return clamp * np.sqrt(area / vpls.count)


def render_frame(scene, settings: RenderSettings, cancel=None, progress=None,
                 tracer_cache=None, vpls=None) -> RenderResult:
    """Render one frame. `cancel()` is polled; `progress(fraction, message)` reports."""
    report = progress or (lambda fraction, message: None)
    check = cancel or (lambda: False)
    check_renderable(scene)
    timings = {}
    t0 = time.perf_counter()
    report(0.0, "Preparing scene")
    frame = prepare_frame(scene, tracer_cache)
    timings["prepare"] = time.perf_counter() - t0
    warnings = list(scene.warnings)
    if frame.dropped_triangles:
        warnings.append(f"Skipped {frame.dropped_triangles} degenerate triangles")
    if not frame.emitters:
        warnings.append("The scene has no light with non-zero power: the image is black "
                        "except for the background")
    rng = np.random.default_rng(settings.seed)

    t = time.perf_counter()
    report(0.02, "Tracing camera rays")
    gb = build_gbuffer(frame, scene.camera, settings.aa_samples, rng)
    timings["gbuffer"] = time.perf_counter() - t
    if check():
        raise Cancelled()

    t = time.perf_counter()
    report(0.05, "Shooting particles")
    if vpls is None:
        vpls = vpl.trace_vpls(frame, settings.particles, settings.max_bounces,
                              seed=settings.seed, cancel=check)
    timings["vpls"] = time.perf_counter() - t
    if check():
        raise Cancelled()

    t = time.perf_counter()
    report(0.1, "Direct light")
    E_direct = gather.direct_irradiance(frame, gb, settings.light_samples, rng, check)
    timings["direct"] = time.perf_counter() - t
    if check():
        raise Cancelled()

    t = time.perf_counter()
    dmin = clamp_distance(frame, vpls, settings.clamp)
    k = max(1, settings.interleave)
    E_indirect = gather.indirect_irradiance(
        frame, gb, vpls, dmin,
        interleaving.sample_subsets(gb.width, gb.height, gb.samples, k),
        interleaving.subset_count(k, gb.samples), check,
        lambda f: report(0.25 + 0.75 * f, f"Gathering {vpls.count} VPLs"))
    E_indirect = interleaving.filter_sample_layers(E_indirect, gb, k)
    timings["indirect"] = time.perf_counter() - t
    if check():
        raise Cancelled()

    result = RenderResult(compose_passes(gb, E_direct, E_indirect, scene.world_radiance,
                                         settings.film_transparent), warnings=warnings)
    result.stats = {"vpls": vpls.count, "triangles": len(frame.triangles),
                    "clamp_distance": dmin, "time": time.perf_counter() - t0,
                    **{f"time_{k}": v for k, v in timings.items()}}
    result.vpls = vpls
    return result


def compose_passes(gb, E_direct, E_indirect, world_radiance, film_transparent):
    """Radiance = emission + albedo/pi * (E_direct + E_indirect), averaged per pixel."""
    brdf = gb.albedo / np.pi
    visible = gb.hit & ~gb.holdout
    direct = np.where(visible[:, None], gb.emission + brdf * E_direct, 0.0)
    indirect = np.where(visible[:, None], brdf * E_indirect, 0.0)
    background = ~gb.hit & (not film_transparent)
    direct[background] = np.maximum(np.nan_to_num(np.asarray(world_radiance, np.float64)), 0.0)
    alpha = (visible | background).astype(np.float64)
    combined = np.concatenate([direct + indirect, alpha[:, None]], -1)
    depth = gb.depth[:, None]
    passes = {
        "Combined": gb.pixel_mean(combined),
        "IRAD Direct": gb.pixel_mean(direct),
        "IRAD Indirect": gb.pixel_mean(indirect),
        "Depth": gb.pixel_mean(depth),
        "Normal": gb.pixel_mean(gb.normal),
        "Albedo": gb.pixel_mean(np.where(gb.hit[:, None], gb.albedo, 0.0)),
    }
    return {name: sanitize(image).astype(np.float32) for name, image in passes.items()}


def sanitize(image):
    """No NaN, Inf or negative radiance ever leaves the renderer."""
    return np.nan_to_num(image, nan=0.0, posinf=0.0, neginf=0.0)
