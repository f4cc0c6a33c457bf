"""Incremental Instant Radiosity (Laine, Saransaari, Kontkanen, Lehtinen, Aila 2007).

For point and spot lights (radius 0) whose geometry stays: every light keeps a set of
sites, directions in its 2D domain (the sphere of directions; a spot's cone is a cap of
it) with the path a particle sent that way took. Each frame, after the light moved:
- a site is invalid when the light's new position cannot see its first hit, when the
  hit leaves the spot's cone, or when an escaped ray now hits something (sec. 3.1);
- valid sites keep their first hit y, so their direction becomes y - light;
- sites crowded closer than 3/4 of the ideal spacing go, worst first, and sites are added
  at the centre of the largest empty circle (sec. 3.2), within a per-frame budget;
- a site's power is its Voronoi cell's: the light's intensity integrated over the
  directions closer to it than to any other site (a fixed quadrature set), so the sites'
  powers sum to the light's power (sec. 3.3).
The nearest-site searches behind the last two (direction_search.py) go through grids
of cubes over the directions, so their cost grows with the quadrature and site counts,
not with their product; the domain's grid is kept while the domain stays. New sites'
bounces draw on one Halton sequence (Keller 1997).
Beyond the paper's one bounce, each site keeps its whole multi-bounce path: the later
vertices do not depend on where the light is, and their flux scales with the first
hit's, so they stay unbiased for that first hit. Other emitters get classic VPLs,
kept while those emitters and the geometry stay.
"""
from dataclasses import dataclass, replace

import numpy as np

from . import sampling, vpl
from .temporal import emitters_fingerprint
from .direction_search import (DirectionGrid, chord, largest_empty_circles, nearest_point,
                               nearest_sites, site_spacing)
from .lights import PointEmitter, SpotEmitter

BUDGET_SHARE = 0.05          # new sites per frame, as a share of the target count
CROWDED = 0.75               # sites closer than this share of the ideal spacing may go
REBUILD_BELOW = 0.5          # fewer valid sites than this share of the target: rebuild
QUADRATURE_DIRECTIONS = 8192
HALTON_BLOCK = 4096          # bounce points drawn at once
PATH_VERTICES = 1 << 16      # VPL ids: site serial * PATH_VERTICES + bounce
_BOUNCE_DIMS = 3


def fibonacci_sphere(count):
    """Nearly uniform unit directions (a spherical Fibonacci lattice)."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


@dataclass
class LightSites:
    """One light's sites: direction, first hit and the normal on its lit side (NaN
    when the ray escaped), serial number (unique over the job) and the path's VPLs per
    unit power sent along the direction, with their site index."""
    direction: np.ndarray
    hit: np.ndarray
    hit_normal: np.ndarray
    serial: np.ndarray
    unit_vpls: vpl.VPLs
    owner: np.ndarray

    def keep(self, mask):
        index = np.cumsum(mask) - 1
        own = mask[self.owner]
        return LightSites(self.direction[mask], self.hit[mask], self.hit_normal[mask],
                          self.serial[mask], self.unit_vpls.subset(own),
                          index[self.owner[own]])

    def vpl_ids(self):
        """A VPL's identity across frames: its site's serial and its bounce."""
        return self.serial[self.owner] * PATH_VERTICES + self.unit_vpls.bounce


def incremental_emitter(emitter):
    return isinstance(emitter, (PointEmitter, SpotEmitter)) and emitter.delta


class IncrementalVPLs:
    """The persistent VPLs of one render job; update() is called once per frame."""

    def __init__(self):
        self.sites = None
        self.surfaces = None          # Frame.surfaces_key of the frame the sites are in
        self.rays = 0                 # rays traced by the last update (for cost checks)
        self.compared = 0             # direction pairs compared by the last update
        self.paths = 0                # sites created so far: their Halton index
        self._halton = (None, 0, np.zeros((0, 0)))   # (seed and dims, first index, points)
        self.quadrature = fibonacci_sphere(QUADRATURE_DIRECTIONS)
        self._domains = {}            # (domain mask, target) -> DirectionGrid
        self._classic = (None, None)  # (key, VPLs) of the emitters that are not incremental

    def update(self, frame, settings):
        lights = [e for e in frame.emitters if incremental_emitter(e)]
        others = [e for e in frame.emitters if not incremental_emitter(e)]
        surfaces = frame.surfaces_key   # the paths' bounces depend on the materials too
        if self.sites is None or self.surfaces != surfaces or len(self.sites) != len(lights):
            self.sites = [None] * len(lights)
            self.paths = 0
            self.surfaces = surfaces
        counts = (vpl.particles_per_emitter(frame.emitters, settings.particles)
                  if frame.emitters else [])
        targets = [int(c) for e, c in zip(frame.emitters, counts) if incremental_emitter(e)]
        self.rays = self.compared = 0
        found, ids, removed, added = [], [], 0, 0
        for k, (light, target) in enumerate(zip(lights, targets)):
            domain = self._domain(light, target)
            sites, gone = self._validate(frame, light, self.sites[k], target, domain)
            if sites is not None and len(sites.direction) < REBUILD_BELOW * target:
                sites = None   # a jump lost most sites: start afresh, not 5% a frame
            sites, cell, new = self._refill(frame, light, sites, target, domain, settings)
            self.sites[k] = sites
            removed, added = removed + gone, added + new
            found.append(self._weighted_vpls(light, sites, domain, cell))
            ids.append(sites.vpl_ids() if sites is not None else np.zeros(0, np.int64))
        if others:
            found.append(self._classic_vpls(frame, others, int(sum(
                c for e, c in zip(frame.emitters, counts) if not incremental_emitter(e))),
                settings))
            ids.append(-1 - np.arange(found[-1].count))   # the same while they are kept
        vpls = vpl.VPLs.concatenate(found)
        return vpls, {'removed': removed, 'added': added, 'rays': self.rays,
                      'incremental_vpls': int(sum(v.count for v in found[:len(lights)])),
                      'compared': self.compared,
                      'vpl_ids': np.concatenate(ids) if ids else np.zeros(0, np.int64)}

    def _classic_vpls(self, frame, others, particles, settings):
        """Classic VPLs of the other emitters, kept while they, the geometry and the
        settings stay (then tracing them again would give the very same VPLs)."""
        key = (self.surfaces, emitters_fingerprint(others), particles,
               settings.seed, settings.max_bounces, settings.sequence)
        if key != self._classic[0]:
            vpls = vpl.trace_vpls(replace(frame, emitters=others), particles,
                                  settings.max_bounces, seed=settings.seed,
                                  sequence=settings.sequence)
            self._classic = (key, vpls)
        return self._classic[1]

    def _validate(self, frame, light, sites, target, domain):
        """Drop sites the light's new position cannot use (Laine 2007, sec. 3.1)."""
        if sites is None or len(sites.direction) == 0:
            return sites, 0
        real = np.isfinite(sites.hit[:, 0])
        to_hit = np.where(real[:, None], sites.hit - light.position, sites.direction)
        dist = np.linalg.norm(to_hit, axis=1)
        direction = to_hit / np.maximum(dist, 1e-30)[:, None]
        ok = light.attenuation(direction) > 0
        # The light must stay on the lit side of the first hit: through a two-sided
        # wall it sees the surface, not the VPL.
        ok[real] &= np.einsum('ij,ij->i', sites.hit_normal[real], direction[real]) < 0
        eps = frame.offset()
        r = np.flatnonzero(real & ok)
        ok[r] &= ~frame.tracer.occluded(np.broadcast_to(light.position, (len(r), 3)),
                                        direction[r], dist[r] - 4 * eps)
        p = np.flatnonzero(~real & ok)
        ok[p] &= ~frame.tracer.intersect(np.broadcast_to(light.position, (len(p), 3)),
                                         direction[p]).hit
        self.rays += len(r) + len(p)
        sites = replace(sites, direction=direction).keep(ok)
        spare = max(0, int(BUDGET_SHARE * target) - int((~ok).sum()))
        return self._thin(sites, spare, self._area(len(domain.points))), int((~ok).sum())

    def _thin(self, sites, spare, area):
        """Remove up to `spare` of the most crowded sites (closer to a neighbour than
        3/4 of the ideal spacing; Laine 2007 sec. 3.2): the refill puts them back where
        the domain is emptiest."""
        count = len(sites.direction)
        if count < 3 or spare == 0:
            return sites
        # Cubes of the crowding distance: one ring around a site holds every neighbour
        # that close (the others are not needed).
        crowding = CROWDED * site_spacing(area, count)
        grid = DirectionGrid(sites.direction, crowding)
        _, cosine, compared = nearest_point(grid, sites.direction, skip_self=True, exact=False)
        self.compared += compared
        nearest = chord(cosine)
        crowded = np.flatnonzero(nearest < crowding)
        drop = crowded[np.argsort(nearest[crowded])][:spare]
        mask = np.ones(count, bool)
        mask[drop] = False
        return sites.keep(mask)

    def _refill(self, frame, light, sites, target, domain, settings):
        """Add sites at the largest empty circles, up to the per-frame budget (the whole
        target on the first frame). Returns the sites, the Voronoi cell (site index) of
        every domain direction, and the number of sites added."""
        have = 0 if sites is None else len(sites.direction)
        budget = target if sites is None else max(1, int(BUDGET_SHARE * target))
        count = min(budget, max(target - have, 0)) if len(domain.points) else 0
        if sites is None and count:
            new_dirs = self._lattice(light, count, domain.points)
            sites = self._trace_sites(frame, light, new_dirs, settings)
            return sites, self._voronoi_cells(sites.direction, domain)[0], len(new_dirs)
        if sites is None:
            return sites, np.zeros(0, np.int64), 0
        cell, best = self._voronoi_cells(sites.direction, domain)
        if count <= 0:
            return sites, cell, 0
        chosen, cell, compared = largest_empty_circles(domain, best, cell, count, have)
        self.compared += compared
        added = self._trace_sites(frame, light, domain.points[chosen], settings)
        return LightSites(np.concatenate([sites.direction, added.direction]),
                          np.concatenate([sites.hit, added.hit]),
                          np.concatenate([sites.hit_normal, added.hit_normal]),
                          np.concatenate([sites.serial, added.serial]),
                          vpl.VPLs.concatenate([sites.unit_vpls, added.unit_vpls]),
                          np.concatenate([sites.owner, added.owner + have])), cell, len(chosen)

    def _lattice(self, light, count, domain):
        """First frame: a Fibonacci lattice over the domain, sized to hold `count` sites."""
        lattice = fibonacci_sphere(int(count * len(self.quadrature) / len(domain)) + 1)
        return lattice[light.attenuation(lattice) > 0]

    def _trace_sites(self, frame, light, directions, settings):
        """New sites: one light path per direction, with unit power."""
        count = len(directions)
        serial = self.paths + np.arange(count)   # the sites' Halton indices
        origin = np.broadcast_to(light.position, (count, 3))
        vpls, owner = vpl.follow_paths(frame, origin, directions, np.ones((count, 3)),
                                       self._bounce_points(count, settings), settings.max_bounces)
        self.rays += int(vpls.count + count)
        first, first_normal = np.full((count, 3), np.nan), np.full((count, 3), np.nan)
        is_first = vpls.bounce == 1
        first[owner[is_first]] = vpls.position[is_first]
        first_normal[owner[is_first]] = vpls.normal[is_first]
        return LightSites(directions, first, first_normal, serial, vpls, owner)

    def _voronoi_cells(self, directions, domain):
        """Nearest site (index, cosine) of every domain direction."""
        cell, best, compared = nearest_sites(domain, directions)
        self.compared += compared
        return cell, best

    def _bounce_points(self, count, settings):
        """The next `count` points of one scrambled Halton sequence for the sites' bounces:
        the sites ever created stay stratified (Keller 1997 sec. 3), so their Russian
        roulette keeps each bounce's total flux close to its expectation. Drawn in blocks:
        scrambling a call's digits costs more than its few points."""
        dims = _BOUNCE_DIMS * settings.max_bounces
        key, start, block = self._halton
        if key != (settings.seed, dims) or not start <= self.paths <= start + len(block) - count:
            start = self.paths
            block = sampling.halton(max(count, HALTON_BLOCK), dims, seed=settings.seed + 1,
                                    start=start + 1)
            self._halton = ((settings.seed, dims), start, block)
        self.paths += count
        return block[self.paths - count - start:self.paths - start]

    def _domain(self, light, target):
        """The quadrature directions of the light's domain (a spot: its cone's cap) in a
        grid of cubes of 0.8 times the target's site spacing (nearly every direction has a
        site that close: the fewest pairs, measured), kept while the domain stays."""
        inside = light.attenuation(self.quadrature) > 0
        key = (hash(inside.tobytes()), target)
        if key not in self._domains:
            if len(self._domains) > 8:
                self._domains.clear()
            area = self._area(int(inside.sum()))
            self._domains[key] = DirectionGrid(self.quadrature[inside],
                                               0.8 * site_spacing(area, target))
        return self._domains[key]

    def _area(self, directions):
        """Solid angle [sr] of a domain of this many quadrature directions."""
        return 4 * np.pi * directions / len(self.quadrature)

    def _weighted_vpls(self, light, sites, domain, cell):
        """Site power = intensity integrated over its Voronoi cell (Laine 2007 sec. 3.3),
        by quadrature over the domain's directions."""
        if sites is None or len(sites.direction) == 0:
            return vpl.VPLs.empty()
        weight = light.intensity[None, :] * (light.attenuation(domain.points) * 4 * np.pi
                                             / len(self.quadrature))[:, None]
        power = np.stack([np.bincount(cell, weight[:, c], minlength=len(sites.direction))
                          for c in range(3)], -1)
        out = sites.unit_vpls.subset(slice(None))
        out.flux = sites.unit_vpls.flux * power[sites.owner]
        return out
