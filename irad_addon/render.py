"""One frame, end to end: G-buffer, VPLs, direct and indirect gather, passes."""
import contextlib
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from . import (antialiasing, bias_compensation, direct_light, direct_lightcuts, gather,
               geometry, interleaving, mirrors, rays, temporal, transfer_reuse, variants)
from .frame import check_renderable, prepare_frame
from .gbuffer import build_gbuffer


@dataclass
class RenderSettings:
    particles: int = 1536        # ~3700 VPLs in the Cornell boxes: against 2048, 11% less
                                 # time for 7% more relMSE (area light), 4% (point light)
    max_bounces: int = 32        # Russian roulette ends most paths long before this
    clamp: float = 5.0           # VPL clamping distance in units of the mean VPL spacing:
                                 # with bias compensation, 5 has 9% / 6% less relMSE than
                                 # 3 on the area- / point-lit Cornell boxes, 6% more in
                                 # the sun-lit room, at the same cost
    aa_samples: int = 1          # shaded camera samples per pixel (what the gather costs):
                                 # edges have their coverage samples, direct light its
                                 # light samples; 1 takes 25-30% off the Cornell boxes'
                                 # time against 4 (with 4 x the light samples, 2 x the
                                 # budget) for +3% / -3% relMSE, same in the sun-lit room
    coverage_samples: int = 16   # camera rays per pixel for edges (antialiasing.py)
    interleave: int = 4          # k: k x k interleaved VPL subsets + discontinuity buffer
    bias_compensation: bool = True   # restore the energy clamping removes (Kollig & Keller)
    shadow_ray_budget: float = 256.0  # shadow-ray roulette: ~most rays per pixel sample,
                                      # over all k x k interleaved groups (area-lit box at
                                      # one sample per pixel: 128 has 8% more relMSE for
                                      # 10% less time; two rooms 25% more)
    use_lightcuts: bool = False  # gather a light-tree cut per point instead of every VPL
    lightcut_error: float = 0.02
    max_cut: int = 1000
    light_samples: int = 16      # shadow rays per shading sample to an area light or mesh
    seed: int = 0
    variant: str = 'CLASSIC'
    sequence: str = 'HALTON'     # particle sequence: sampling.SEQUENCES
    film_transparent: bool = False
    temporal_reuse: bool = True  # reuse the last frame's VPLs while lights and geometry stay
    temporal_frames: int = 1     # N: classic IR gathers the paths of the last N frames


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


# Camera samples per band of rows: bounds the G-buffer and gather temporaries
# (~200 bytes a sample) so that 1920x1080 with many VPLs stays well under 2 GB.
SAMPLES_PER_BAND = 1 << 19


def band_samples(settings):
    """Samples per pixel that size the bands: the shading samples, plus the coverage
    samples at a quarter (they hold a G-buffer row each but no gather temporaries)."""
    coverage = settings.coverage_samples if settings.coverage_samples > settings.aa_samples else 0
    return settings.aa_samples + coverage // 4


def row_bands(height, width, samples, interleave):
    """(first, stop) row ranges covering the image, each a whole number of tiles."""
    k = max(1, interleave)
    rows = max(k, (SAMPLES_PER_BAND // max(1, width * samples)) // k * k)
    return [(y, min(height, y + rows)) for y in range(0, height, rows)]


class _Tally:
    """Accumulates wall time per stage, and per-band averages, over the bands."""

    def __init__(self):
        self.seconds = {}
        self.averages = {}

    def add(self, stage, since):
        self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - since

    def count(self, name, value):
        self.averages.setdefault(name, []).append(value)


def render_frame(scene, settings: RenderSettings, cancel=None, progress=None,
                 tracer_cache=None, vpls=None, path_window=None,
                 variant_state=None, frame_number=None, shot=None) -> RenderResult:
    """Render one frame. `cancel()` is polled; `progress(fraction, message)` reports.
    `path_window` (temporal.PathWindow) keeps VPLs across the frames `frame_number` of
    the animation `shot` (any hashable name)."""
    report = progress or (lambda fraction, message: None)
    check = cancel or (lambda: False)
    check_renderable(scene)
    tally = _Tally()
    t0 = time.perf_counter()
    report(0.0, "Preparing scene")
    frame = prepare_frame(scene, tracer_cache)
    tally.add("prepare", t0)
    warnings = list(scene.warnings)
    if frame.dropped_triangles:
        warnings.append(f"Skipped {frame.dropped_triangles} degenerate triangles")
    if not frame.emitters:
        warnings.append("The scene has no light with non-zero power: the image is black "
                        "except for the background")

    t = time.perf_counter()
    report(0.02, "Shooting particles")
    window = path_window if settings.temporal_reuse and vpls is None else None
    batch, frames = 0, window_frames(settings)
    if window is not None:
        setup_key = temporal.light_setup_key(scene, settings, frame.surfaces_key)
        vpls = window.lookup(setup_key, settings, frames, frame_number, shot)
        batch = window.next_batch
    variant_info = {}
    cam = scene.camera
    bands = row_bands(cam.height, cam.width, band_samples(settings), settings.interleave)
    first_gbuffer = None
    traced = vpls is None
    if traced and settings.variant in BESIDE_CAMERA_RAYS:
        vpls, variant_info, first_gbuffer = vpls_beside_camera_rays(
            frame, settings, variant_state, check, bands[0], batch)
    elif traced:
        vpls, variant_info = variants.vpls_for_frame(frame, settings, variant_state, check,
                                                     batch)
    if window is not None and traced:
        vpls = window.store(setup_key, vpls, frames)
    tally.add("vpls", t)
    if check():
        raise Cancelled()

    passes = {name: np.zeros((cam.height, cam.width, c), np.float32)
              for name, c in PASS_CHANNELS.items()}
    dmin = clamp_distance(frame, vpls, settings.clamp)
    transfer = reusable_transfer(frame, settings, variant_state, variant_info, vpls)
    if transfer is not None:
        dmin = transfer[0].begin(temporal.still_camera_key(frame, settings), dmin)
    # With lightcuts, area lights and emissive meshes join as many point lights.
    light_points = direct_lightcuts.light_points(frame) if settings.use_lightcuts else None
    for number, rows in enumerate(bands):
        def band_progress(fraction, message):
            report(0.05 + 0.95 * (number + fraction) / len(bands), message)
        band = render_band(frame, vpls, settings, rows, dmin, check, band_progress, tally,
                           light_points, transfer, first_gbuffer if number == 0 else None)
        for name, image in band.items():
            passes[name][rows[0]:rows[1]] = image
    result = RenderResult(passes, warnings=warnings)
    result.stats = {"vpls": vpls.count, "triangles": len(frame.triangles),
                    "path_frames": window.batches if window is not None else 1,
                    "clamp_distance": dmin, "bands": len(bands),
                    "variant": variant_info.get("variant", settings.variant),
                    "variant_reason": variant_info.get("reason", "VPLs of an earlier frame"),
                    "time": time.perf_counter() - t0,
                    **{k: float(np.mean(v)) for k, v in tally.averages.items()},
                    **{f"time_{k}": v for k, v in tally.seconds.items()}}
    result.vpls = vpls
    return result


# Variants whose VPLs keep nothing of the camera's samples (incremental IR may keep
# their transfer): traced on a worker while this thread traces the first band's camera
# rays (the variants that look through the camera trace their own small pilot).
BESIDE_CAMERA_RAYS = ('CLASSIC', 'BIDIRECTIONAL', 'METROPOLIS')


def window_frames(settings):
    """N of the path window: classic IR's paths do not depend on the camera; the other
    variants' do (or keep their own, incremental), so they keep one frame's."""
    return max(1, settings.temporal_frames) if settings.variant == 'CLASSIC' else 1


def vpls_beside_camera_rays(frame, settings, variant_state, check, rows, batch=0):
    """(VPLs, variant info, (G-buffer, generator) of the band `rows`): the VPLs are
    traced whole on a worker while this thread traces the band's camera rays; a cancel
    seen meanwhile stops the particles' bounces."""
    stop = threading.Event()
    job = rays.submit_whole(variants.vpls_for_frame, frame, settings, variant_state,
                            stop.is_set, batch)
    try:
        first_gbuffer = band_gbuffer(frame, settings, rows)
    finally:
        if check():
            stop.set()
    # The pool is idle at a frame's start: a worker has the VPLs at once, and taking
    # them back here would only trade one thread for the other.
    vpls, variant_info = job.result(take=False)
    return vpls, variant_info, first_gbuffer


def band_gbuffer(frame, settings, rows):
    """(G-buffer, generator) of the shading samples of image rows (first, stop) and
    their halo: the generator of the band, drawn from for its camera rays first."""
    cam = frame.scene.camera
    # One generator per band and seed: the same image for a given seed and band layout.
    rng = np.random.default_rng([settings.seed, rows[0]])
    gb = build_gbuffer(frame, cam, settings.aa_samples, rng, padded_rows(cam, rows, settings))
    return gb, rng


def padded_rows(cam, rows, settings):
    """The band's rows and one tile more above and below, for the discontinuity buffer."""
    halo = settings.interleave if settings.interleave > 1 else 0
    return max(0, rows[0] - halo), min(cam.height, rows[1] + halo)


def reusable_transfer(frame, settings, variant_state, variant_info, vpls):
    """(TransferCache, VPL ids) when the VPLs' transfer to the camera may be kept for
    the next frames (transfer_reuse.py): incremental IR's VPLs with their ids, gathered
    without lightcuts, every interleaved group holding some, within the memory bound."""
    ids = variant_info.get('vpl_ids')
    if variant_state is None or ids is None or settings.use_lightcuts or len(ids) != vpls.count:
        return None
    subsets = interleaving.subset_count(settings.interleave, settings.aa_samples)
    samples = frame.scene.camera.width * frame.scene.camera.height * settings.aa_samples
    if not transfer_reuse.fits(samples, vpls.count, subsets):
        return None
    if len(np.unique(transfer_reuse.interleaved_group(ids, subsets))) < subsets:
        return None   # a group without VPLs would leave its pixels without indirect light
    return variant_state.transfer, ids


def render_band(frame, vpls, settings, rows, dmin, check, report, tally, light_points=None,
                transfer=None, prebuilt=None):
    """Passes for image rows (first, stop). The G-buffer reaches one tile further up
    and down so the discontinuity buffer sees whole windows at the band's edges.
    transfer: (TransferCache, VPL ids) to keep the G-buffers and the VPLs' transfer.
    prebuilt: the band's band_gbuffer, if already traced."""
    cam = frame.scene.camera
    k = max(1, settings.interleave)
    padded = padded_rows(cam, rows, settings)

    t = time.perf_counter()
    report(0.0, "Tracing camera rays")
    kept = transfer[0].bands.get(rows) if transfer is not None else None
    film = coverage = None
    if kept is not None:   # the same camera, geometry and settings: the same G-buffers
        (gb, film), coverage = kept.gbuffers, kept.coverage
        rng = np.random.default_rng([settings.seed, rows[0]])
        rng.bit_generator.state = kept.rng_state
    else:
        gb, rng = prebuilt if prebuilt is not None else band_gbuffer(frame, settings, rows)
        first_state = rng.bit_generator.state   # a kept band's frames start here
    tally.add("gbuffer", t)

    lightcuts = (gather.Lightcuts(settings.lightcut_error, settings.max_cut)
                 if settings.use_lightcuts else None)
    subset_of_sample = interleaving.sample_subsets(gb.width, padded, gb.samples, k)
    subsets = interleaving.subset_count(k, gb.samples)
    # Each sample gathers one of k x k groups: its share of the budget. The filter
    # averages (2k)^2 of them, so the roulette's noise in the image does not depend on k.
    budget = settings.shadow_ray_budget / k ** 2
    gather_stats = {}
    # The clamp's compensation, one whole task, is queued first, so that it does not
    # end the band alone on one worker; the gather's tasks follow, and this thread
    # takes those still queued when it is done with its own part (PendingIrradiance).
    compensation = start_compensation(frame, gb, vpls, dmin, subset_of_sample, subsets,
                                      settings, rows, budget, beside=transfer is None)
    pending = None
    if transfer is None:
        # The VPL gather runs on the pool's workers while this thread does the rest of
        # the band with its own rays (rays.on_calling_thread): no core idles through
        # the serial parts of direct light and film.
        report(0.05, f"Gathering {vpls.count} VPLs")
        pending = gather.start_indirect(frame, gb, vpls, dmin, subset_of_sample, subsets,
                                        lightcuts, budget, seed=(settings.seed, rows[0]))
    try:
        with rays.on_calling_thread(pending.running) if pending else contextlib.nullcontext():
            E_direct, new_film, refined, E_refined = band_direct_light(
                frame, gb, settings, rows, padded, rng, check, report, tally, light_points,
                lightcuts, wants_film=kept is None, keeps_film=transfer is not None)
            if new_film is not None:
                film, coverage = new_film
            if transfer is not None and kept is None:
                kept = transfer[0].bands[rows] = transfer_reuse.BandTransfer(
                    (gb, film), first_state, coverage=coverage)
            mirrored_direct, E_more = mirrored_light(
                frame, gb, vpls, dmin, subset_of_sample, subsets, settings, rng, check,
                report, tally)
    except BaseException:   # cancelled or failed: the workers stop too
        if pending:
            pending.stop.set()
        raise
    if mirrored_direct is not None:
        E_direct = E_direct + mirrored_direct   # kept apart for film_direct

    t = time.perf_counter()
    if pending is not None:
        E_indirect = pending.wait(check, lambda f: report(0.5 + 0.4 * f, "Gathering VPLs"),
                                  gather_stats)
    else:
        report(0.5, f"Gathering {vpls.count} VPLs, new ones only")
        E_indirect, gather_stats["shadow_rays_per_point"] = \
            transfer_reuse.reused_indirect_irradiance(
                frame, gb, vpls, transfer[1], dmin, subset_of_sample, subsets, kept, check,
                budget, seed=(settings.seed, rows[0]))
    E_indirect += E_more
    if compensation is not None:
        E_compensation, seconds = compensation.result()
        E_indirect += E_compensation
        tally.seconds["bias_compensation"] = seconds
    tally.count("shadow_rays_per_point", gather_stats.get("shadow_rays_per_point", 0.0))
    tally.add("indirect", t)
    E_indirect = interleaving.filter_sample_layers(E_indirect, gb, k)
    if check():
        raise Cancelled()
    if film is not None:
        t = time.perf_counter()
        E_direct = film_direct(coverage, E_direct, mirrored_direct, refined, E_refined)
        E_indirect = coverage.carry(E_indirect)
        if kept is None or kept.still is None:
            # The Normal pass keeps the shading samples' interpolated normals.
            film.normal = gb.pixel_mean(gb.normal).reshape(-1, 3)[film.pixel]
        gb = film
        tally.add("coverage", t)
    if kept is not None and kept.still is None:
        kept.still = still_passes(gb, settings.film_transparent)
        if film is not None:   # from now on only its pixels and mirror terms are read
            kept.gbuffers = (kept.gbuffers[0], transfer_reuse.film_only(film))
    band = compose_passes(gb, E_direct, E_indirect, frame.scene.world_radiance,
                          settings.film_transparent, kept.still if kept else None)
    crop = slice(rows[0] - padded[0], rows[1] - padded[0])
    return {name: image[crop] for name, image in band.items()}


def band_direct_light(frame, gb, settings, rows, padded, rng, check, report, tally,
                      light_points, lightcuts, wants_film, keeps_film):
    """(E_direct, (film, coverage), refined, E_refined) of a band's shading samples gb:
    direct light, the film G-buffer and its CoverageMap (antialiasing.py; None without
    coverage samples or unless `wants_film`), and the film samples `refined` on hard
    shadow edges with their own direct light E_refined (None: none)."""
    t = time.perf_counter()
    report(0.1, "Direct light")
    cam = frame.scene.camera
    refined = E_refined = None
    wants_film = wants_film and settings.coverage_samples > settings.aa_samples
    # Hard shadow edges get their own coverage samples' direct light (antialiasing.py);
    # not with kept transfer, whose film must stay the same from frame to frame.
    edges = shadow_edges = None
    if wants_film and not keeps_film and light_points is None:
        edges = antialiasing.surface_edges(gb)
        shadow_edges = antialiasing.HardShadowEdges(gb, edges)
    if light_points is None:
        E_direct = direct_light.direct_irradiance(frame, gb, settings.light_samples, rng,
                                                  check, shadow_edges=shadow_edges)
    else:
        direct_stats = {}
        E_direct = direct_lightcuts.direct_irradiance(frame, *light_points, gb,
                                                      settings.light_samples, rng, lightcuts,
                                                      check, direct_stats)
        tally.count("direct_shadow_rays_per_point",
                    direct_stats.get("shadow_rays_per_point", 0.0))
    tally.add("direct", t)
    if check():
        raise Cancelled()
    if not wants_film:
        return E_direct, None, refined, E_refined
    t = time.perf_counter()
    # A generator of its own: a kept band's later frames, which keep the film, draw
    # the same light samples as its first.
    film_rng = np.random.default_rng([settings.seed, rows[0], 1])
    flagged = shadow_edges.pixels(E_direct) if shadow_edges is not None else None
    film, coverage = antialiasing.film_gbuffer(frame, cam, gb, settings.coverage_samples,
                                               film_rng, padded, flagged, edges)
    tally.add("gbuffer", t)
    if flagged is not None:
        t = time.perf_counter()
        refined = antialiasing.shadow_edge_samples(film, coverage, flagged)
        per_ray = max(1, settings.light_samples * settings.aa_samples
                      // settings.coverage_samples)
        E_refined = direct_light.direct_irradiance(   # as many shadow rays per pixel
            frame, antialiasing.take_samples(film, refined), per_ray, film_rng, check)
        tally.count("shadow_edge_pixels", float(flagged.mean()))
        tally.add("direct", t)
    return E_direct, (film, coverage), refined, E_refined


def mirrored_light(frame, gb, vpls, dmin, subset_of_sample, subsets, settings, rng, check,
                   report, tally):
    """(direct light (S, 3), indirect light (S, 3)) that reaches the samples through
    mirrors; (None, zeros) in scenes without mirrors (the mirror code is skipped)."""
    if frame.mirror is None:
        return None, np.zeros((len(gb.hit), 3))
    t = time.perf_counter()
    report(0.3, "Light through mirrors")
    mirrored = mirrors.mirrored_irradiance(frame, gb, vpls, dmin, subset_of_sample, subsets,
                                           settings.light_samples, rng, check)
    tally.add("mirrors", t)
    return mirrored


def start_compensation(frame, gb, vpls, dmin, subset_of_sample, subsets, settings, rows,
                       budget, beside):
    """A Future of (the irradiance clamping took, as bias_compensation restores it with
    a VPL gather of `budget` shadow rays per sample where its rays land; seconds), on a
    worker if `beside` (queued behind the gather), else done here; None without bias
    compensation. Its random numbers are its own generator's, so where it
    runs does not change the image."""
    if not settings.bias_compensation:
        return None
    rng = np.random.default_rng([settings.seed, rows[0], 2])

    def compensate():
        t = time.perf_counter()
        E = bias_compensation.clamp_residual_irradiance(
            frame, gb, vpls, dmin, subset_of_sample, subsets, settings.light_samples, rng,
            shadow_ray_budget=budget, seed=(settings.seed, rows[0], 2))
        return E, time.perf_counter() - t
    return rays.submit_whole(compensate) if beside else rays.run_now(compensate)


def film_direct(coverage, E_direct, mirrored_direct, refined, E_refined):
    """Direct light (film samples, 3): carried from the shading samples' E_direct,
    except at the coverage samples `refined` (on hard shadow edges), which have their
    own E_refined plus the light they receive through mirrors, carried (None: none)."""
    out = coverage.carry(E_direct)
    if refined is not None and len(refined):
        out[refined] = E_refined
        if mirrored_direct is not None:
            out[refined] += coverage.carry(mirrored_direct)[refined]
    return out


def compose_passes(gb, E_direct, E_indirect, world_radiance, film_transparent, still=None):
    """Radiance = emission + albedo/pi * (E_direct + E_indirect), averaged per pixel.
    still: the G-buffer's still_passes, if already made."""
    still = still if still is not None else still_passes(gb, film_transparent)
    direct = still["brdf"] * E_direct
    direct += still["emission"]
    direct[still["background"]] = np.maximum(
        np.nan_to_num(np.asarray(world_radiance, np.float64)), 0.0)
    indirect = still["brdf"] * E_indirect
    if gb.throughput is not None:   # seen in mirrors, with the lights they reflect
        direct *= gb.throughput
        indirect *= gb.throughput
        direct += gb.mirrored_light
    direct, indirect = gb.pixel_mean(direct), gb.pixel_mean(indirect)
    passes = {"Combined": np.concatenate([direct + indirect, still["Alpha"]], -1),
              "IRAD Direct": direct, "IRAD Indirect": indirect}
    passes = {name: sanitize(image).astype(np.float32) for name, image in passes.items()}
    return {**passes, **{name: still[name] for name in ("Depth", "Normal", "Albedo")}}


def still_passes(gb, film_transparent):
    """What compose_passes takes from the G-buffer alone (a still camera keeps it): the
    alpha, depth, normal and albedo passes, and per sample the BRDF albedo / pi and the
    emission where a surface is seen, and where the background is."""
    visible = (gb.hit & ~gb.holdout)[:, None]
    background = ~gb.hit & (not film_transparent)
    alpha = (visible[:, 0] | background).astype(np.float64)[:, None]
    passes = {"Alpha": gb.pixel_mean(alpha), "Depth": gb.pixel_mean(gb.depth[:, None]),
              "Normal": gb.pixel_mean(gb.normal),
              "Albedo": gb.pixel_mean(np.where(gb.hit[:, None], gb.albedo, 0.0))}
    return {**{name: sanitize(image).astype(np.float32) for name, image in passes.items()},
            "brdf": np.where(visible, gb.albedo / np.pi, 0.0),
            "emission": np.where(visible, gb.emission, 0.0), "background": background}


def sanitize(image):
    """No NaN, Inf or negative radiance ever leaves the renderer."""
    return np.nan_to_num(image, nan=0.0, posinf=0.0, neginf=0.0)
