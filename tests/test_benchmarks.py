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
