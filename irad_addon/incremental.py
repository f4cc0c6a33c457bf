"""Incremental Instant Radiosity (Laine, Saransaari, Kontkanen, Lehtinen, Aila 2007).

For point and spot lights (radius 0) whose geometry stays: every light keeps a set of
sites, directions in its 2D domain (the sphere of directions; a spot's cone is a cap of
it) with the path a particle sent that way took. Each frame, after the light moved:
- a site is invalid when the light's new position cannot see its first hit, when the
  hit leaves the spot's cone, or when an escaped ray now hits something (sec. 3.1);
- valid sites keep their first hit y, so their direction becomes y - light;
- sites crowded closer than half the ideal spacing go, worst first, and sites are added
  at the centre of the largest empty circle (sec. 3.2), within a per-frame budget;
- a site's power is its Voronoi cell's: the light's intensity integrated over the
  directions closer to it than to any other site (a fixed quadrature set), so the sites'
  powers sum to the light's power (sec. 3.3).
Beyond the paper's one bounce, each site keeps its whole multi-bounce path: the later
vertices do not depend on where the light is, and their flux scales with the first
hit's, so they stay unbiased for that first hit. Other emitters get classic VPLs.
"""
from dataclasses import dataclass, replace

import numpy as np

from . import vpl
from .lights import PointEmitter, SpotEmitter

BUDGET_SHARE = 0.05          # new sites per frame, as a share of the target count
QUADRATURE_DIRECTIONS = 8192
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
    """One light's sites: direction, first hit (NaN when the ray escaped) and the
    path's VPLs per unit power sent along the direction, with their site index."""
    direction: np.ndarray
    hit: np.ndarray
    unit_vpls: vpl.VPLs
    owner: np.ndarray

    def keep(self, mask):
        index = np.cumsum(mask) - 1
        own = mask[self.owner]
        return LightSites(self.direction[mask], self.hit[mask], self.unit_vpls.subset(own),
                          index[self.owner[own]])


def incremental_emitter(emitter):
    return isinstance(emitter, (PointEmitter, SpotEmitter)) and emitter.delta


class IncrementalVPLs:
    """The persistent VPLs of one render job; update() is called once per frame."""

    def __init__(self):
        self.sites = None
        self.geometry_key = None
        self.rays = 0                 # rays traced by the last update (for cost checks)
        self.quadrature = fibonacci_sphere(QUADRATURE_DIRECTIONS)

    def update(self, frame, settings):
        lights = [e for e in frame.emitters if incremental_emitter(e)]
        others = [e for e in frame.emitters if not incremental_emitter(e)]
        if (self.sites is None or self.geometry_key != frame.tracer.fingerprint
                or len(self.sites) != len(lights)):
            self.sites = [None] * len(lights)
            self.geometry_key = frame.tracer.fingerprint
        counts = (vpl.particles_per_emitter(frame.emitters, settings.particles)
                  if frame.emitters else [])
        targets = [int(c) for e, c in zip(frame.emitters, counts) if incremental_emitter(e)]
        self.rays = 0
        rng = np.random.default_rng([settings.seed, self.rays_seed()])
        found, removed, added = [], 0, 0
        for k, (light, target) in enumerate(zip(lights, targets)):
            sites, gone = self._validate(frame, light, self.sites[k], target)
            sites, new = self._refill(frame, light, sites, target, settings.max_bounces, rng)
            self.sites[k] = sites
            removed, added = removed + gone, added + new
            found.append(self._weighted_vpls(light, sites))
        if others:
            rest = replace(frame, emitters=others)
            found.append(vpl.trace_vpls(rest, int(sum(c for e, c in zip(frame.emitters, counts)
                                                      if not incremental_emitter(e))),
                                        settings.max_bounces, seed=settings.seed))
        vpls = _concat(found)
        return vpls, {'removed': removed, 'added': added, 'rays': self.rays}

    def rays_seed(self):
        return sum(0 if s is None else len(s.direction) for s in self.sites) + 7

    def _validate(self, frame, light, sites, target):
        """Drop sites the light's new position cannot use (Laine 2007, sec. 3.1)."""
        if sites is None or len(sites.direction) == 0:
            return sites, 0
        real = np.isfinite(sites.hit[:, 0])
        to_hit = np.where(real[:, None], sites.hit - light.position, sites.direction)
        dist = np.linalg.norm(to_hit, axis=1)
        direction = to_hit / np.maximum(dist, 1e-30)[:, None]
        ok = light.attenuation(direction) > 0
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
        return self._thin(sites, spare), int((~ok).sum())

    def _thin(self, sites, spare):
        """Remove up to `spare` of the most crowded sites (closer to a neighbour than
        the ideal spacing): the refill puts them back where the domain is emptiest."""
        count = len(sites.direction)
        if count < 3 or spare == 0:
            return sites
        spacing = np.sqrt(4 * np.pi / count)
        nearest = _nearest_other(sites.direction)
        crowded = np.flatnonzero(nearest < 0.75 * spacing)
        drop = crowded[np.argsort(nearest[crowded])][:spare]
        mask = np.ones(count, bool)
        mask[drop] = False
        return sites.keep(mask)

    def _refill(self, frame, light, sites, target, max_bounces, rng):
        """Add sites at the largest empty circles, up to the per-frame budget (the whole
        target on the first frame)."""
        domain = self._domain(light)
        have = 0 if sites is None else len(sites.direction)
        budget = target if sites is None else max(1, int(BUDGET_SHARE * target))
        count = min(budget, max(target - have, 0))
        if count <= 0 or len(domain) == 0:
            return sites, 0
        if sites is None:
            # First frame: a lattice over the domain, sized to hold `count` sites.
            lattice = fibonacci_sphere(int(count * len(self.quadrature) / len(domain)) + 1)
            new_dirs = lattice[light.attenuation(lattice) > 0]
            count = len(new_dirs)
        else:
            new_dirs = _largest_empty_circles(domain, sites.direction, count)
        origin = np.broadcast_to(light.position, (count, 3))
        unit = np.ones((count, 3))
        bounce_u = rng.random((count, _BOUNCE_DIMS * max_bounces))
        vpls, owner = vpl.follow_paths(frame, origin, new_dirs, unit, bounce_u, max_bounces)
        self.rays += int(vpls.count + count)
        first = np.full((count, 3), np.nan)
        is_first = vpls.bounce == 1
        first[owner[is_first]] = vpls.position[is_first]
        added = LightSites(new_dirs, first, vpls, owner)
        if sites is None:
            return added, count
        return LightSites(np.concatenate([sites.direction, new_dirs]),
                          np.concatenate([sites.hit, first]),
                          _concat([sites.unit_vpls, vpls]),
                          np.concatenate([sites.owner, owner + have])), count

    def _domain(self, light):
        """Quadrature directions of the light's domain (a spot: its cone's cap)."""
        return self.quadrature[light.attenuation(self.quadrature) > 0]

    def _weighted_vpls(self, light, sites):
        """Site power = intensity integrated over its Voronoi cell (Laine 2007 sec. 3.3)."""
        if sites is None or len(sites.direction) == 0:
            return vpl.VPLs.empty()
        q = self.quadrature
        weight = light.intensity[None, :] * (light.attenuation(q) * 4 * np.pi / len(q))[:, None]
        cell = np.argmax(q @ sites.direction.T, axis=1)
        power = np.stack([np.bincount(cell, weight[:, c], minlength=len(sites.direction))
                          for c in range(3)], -1)
        out = sites.unit_vpls.subset(slice(None))
        out.flux = sites.unit_vpls.flux * power[sites.owner]
        return out


def _nearest_other(directions):
    """Angular distance (chord) from each direction to its nearest other one."""
    dots = directions @ directions.T
    np.fill_diagonal(dots, -2.0)
    return np.sqrt(np.maximum(2.0 - 2.0 * dots.max(1), 0.0))


def _largest_empty_circles(domain, existing, count):
    """Greedy farthest-point insertion over the domain's quadrature directions: each new
    site goes to the centre of the largest empty circle left (Laine 2007 sec. 3.2)."""
    best = (domain @ existing.T).max(1)
    chosen = []
    for _ in range(min(count, len(domain))):
        i = int(np.argmin(best))
        chosen.append(i)
        best = np.maximum(best, domain @ domain[i])
    return domain[chosen]


def _concat(parts):
    parts = [p for p in parts if p is not None and p.count]
    if not parts:
        return vpl.VPLs.empty()
    return vpl.VPLs(*[np.concatenate([getattr(p, f) for p in parts])
                      for f in ('position', 'normal', 'flux', 'bounce')])
