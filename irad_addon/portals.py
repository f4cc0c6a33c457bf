"""Light portals (Cycles' area lights with Portal set, e.g. in windows): where sun and
world particles enter the scene. They never emit, block or change direct light."""
import numpy as np

from .geometry import dot_rows, patch_area, patch_points, unit_rows
from .scene_data import Portal


def usable_portals(portals, bounds):
    """Portals (Portals) of the scene_data.Portal list with a finite, non-zero area and
    a direction, or None when there are none (particles then start around the scene)."""
    def usable(p):
        numbers = np.concatenate([p.center, p.axis_u, p.axis_v, p.normal]).astype(np.float64)
        area = patch_area(np.asarray(p.axis_u, np.float64), np.asarray(p.axis_v, np.float64),
                          p.shape == 'ELLIPSE')
        return np.isfinite(numbers).all() and area > 0 and np.linalg.norm(p.normal) > 0
    found = [p for p in portals if isinstance(p, Portal) and usable(p)]
    return Portals(found, bounds) if found else None


class Portals:
    """The scene's light portals, where sun and world particles enter. A particle is
    sampled as a line through a portal (a point on it and an inward direction) and
    starts where that line enters the scene's bounding sphere, so that geometry outside
    the opening still shadows it."""

    def __init__(self, portals, bounds):
        def stack(name):
            return np.array([getattr(p, name) for p in portals], np.float64).reshape(-1, 3)
        self.center, self.axis_u, self.axis_v = stack('center'), stack('axis_u'), stack('axis_v')
        self.normal, _ = unit_rows(stack('normal'))
        self.ellipse = np.array([p.shape == 'ELLIPSE' for p in portals], bool)
        self.area = patch_area(self.axis_u, self.axis_v, self.ellipse)
        self.bounds = bounds

    def choose(self, weights, u):
        """Portal per particle with probability weights / sum(weights), and that probability."""
        prob = weights / weights.sum()
        cdf = np.cumsum(prob)
        cdf[-1] = 1.0
        index = np.minimum(np.searchsorted(cdf, u, side='right'), len(cdf) - 1)
        return index, prob[index]

    def points(self, index, u):
        return patch_points(self.center[index], self.axis_u[index], self.axis_v[index],
                            self.ellipse[index], u)

    def inward_crossings(self, index, points, travel):
        """(n,) portals that each line (through a point on portal `index`, along
        `travel`) passes inwards. Every one of them samples that line, so each sample
        is weighted 1 / count: the weights sum to one (Veach 1997, multi-sample MIS)."""
        cos = travel @ self.normal.T                                    # (n, K)
        into = cos > 0
        t = np.einsum('kj,nkj->nk', self.normal, self.center[None] - points[:, None])
        at = points[:, None] + (t / np.where(into, cos, 1.0))[..., None] * travel[:, None]
        a, b = (np.einsum('nkj,kj->nk', at - self.center, axis) / dot_rows(axis, axis)
                for axis in (self.axis_u, self.axis_v))
        inside = np.where(self.ellipse, a * a + b * b <= 1.0, np.maximum(abs(a), abs(b)) <= 1.0)
        crossed = inside & into
        crossed[np.arange(len(index)), index] = True      # its own portal, despite rounding
        return crossed.sum(1)

    def entry_points(self, points, travel):
        """Where the lines through `points` along `travel` enter the scene's bounding
        sphere (1 % margin): particles start there, before anything outside."""
        center, radius = self.bounds
        q = points - center
        b = dot_rows(q, travel)
        t = b + np.sqrt(np.maximum(b * b - dot_rows(q, q) + (1.01 * radius) ** 2, 0.0))
        return points - travel * np.maximum(t, 0.0)[:, None]

    def lines(self, weights, u, travel_of):
        """Particles through the portals: portal chosen by `weights` with u[:, 4], a
        uniform point on it from u[:, 0:2], travel directions travel_of(index). Returns
        (start, travel, index, probability of the portal, MIS weight)."""
        index, prob = self.choose(weights, u[:, 4])
        point = self.points(index, u[:, 0:2])
        travel = travel_of(index)
        share = 1.0 / self.inward_crossings(index, point, travel)
        return self.entry_points(point, travel), travel, index, prob, share
