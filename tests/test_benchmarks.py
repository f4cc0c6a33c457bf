"""The benchmark harness measures what it says: the throughput probe sees the render's
own VPL gather (its pairs, shadow rays and wall time)."""
import bpy

from benchmarks import scenes, throughput


def test_throughput_probe_records_the_render_gathers_own_rays(scene, addon):
    # The exhaustive gather traces a shadow ray for every pixel-VPL pair with a positive
    # term: the probe must record those (most of its pairs), not some other gather's.
    core = addon.irad_addon
    scenes.cornell_box("AREA", 32)
    data = core.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
    row = throughput.measure_config(core, data, "exhaustive gather",
                                    throughput.CONFIGS["exhaustive gather"], 200_000)
    assert row["pairs"] > 100_000, row
    assert 0.3 * row["pairs"] < row["shadow_rays"] <= row["pairs"], row
    assert 0 < row["gather_seconds"] and 0 < row["ratio"], row


def test_equal_error_ratio_bounds_a_competitor_that_never_gets_there():
    from benchmarks import report

    ours = [{"method": report.DEFAULT_METHOD, "particles": 2048, "seconds": 0.12,
             "relmse": 3.2e-3}]
    oidn = [{"method": report.OIDN, "spp": s, "seconds": t, "relmse": e}
            for s, t, e in ((16, 0.26, 6.9e-3), (32, 0.50, 5.1e-3), (64, 0.57, 3.5e-3))]
    eq = report.equal_error_ratio({"runs": ours + oidn, "default_particles": 2048})
    assert eq["competitor"] is None and eq["ratio"] is None
    assert eq["ratio_bound"] == 0.12 / 0.57
    assert report.fmt_equal_error_ratio(eq) == "< 0.21"
    assert "0.57 s" in report.fmt_competitor(eq) and "0.0035" in report.fmt_competitor(eq)
    reached = oidn + [{"method": report.OIDN, "spp": 128, "seconds": 1.2, "relmse": 2e-3}]
    eq = report.equal_error_ratio({"runs": ours + reached, "default_particles": 2048})
    assert 0.57 < eq["competitor"] < 1.2 and "ratio_bound" not in eq
