"""Cycles direct light on point_over_plane matches the analytic image.

Validates the scene builder, the EXR read-back orientation (row 0 = top) and
the metric in one go: the light is off-centre, so a flipped image would fail.
"""
from benchmarks import metrics, reference, scenes


def test_point_over_plane_matches_analytic(scene):
    s = scenes.point_over_plane(height=1.0, power=1000.0, resolution=16, offset=(0.5, 0.8))
    assert s is scene
    engine = s.render.engine
    # A radius-0 point light and centre sampling make direct light noise-free.
    img = reference.cycles_reference(s, 4, direct_only=True, pixel_filter="CENTER")
    assert s.render.engine == engine  # the caller's engine is restored
    expected = scenes.point_over_plane_analytic(s)
    assert img.shape == expected.shape == (16, 16, 3)
    assert metrics.relmse(img, expected) < 1e-3
    assert abs(metrics.relative_bias(img, expected)) < 1e-2
    # Orientation: the light is at +x, +y, so the top-right pixel is the brightest.
    assert img[0, -1, 0] > img[-1, 0, 0]


def test_metrics_basics():
    import numpy as np
    ref = np.ones((2, 2, 3), np.float32)
    assert metrics.relmse(ref, ref) == 0.0
    assert abs(metrics.relative_bias(2 * ref, ref) - 1.0) < 1e-12
    assert abs(metrics.relmse(2 * ref, ref) - 1 / 1.01) < 1e-9
    assert metrics.reference_relmse(ref, ref) == 0.0
