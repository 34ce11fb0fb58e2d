"""Capture settings a model records of its calibration presses, and what `nlips infer` names when a press differs."""

from nlipscalib.core.sensor_record import capture_settings, common_settings, setting_differences


def _twin_meta(spp=8, bounces=1, seed=3, exposure=1.0):
    scene = {
        "name": "nlipstac",
        "camera": {"width": 96},
        "render": {"spp": spp, "bounces": bounces, "seed": seed, "threads": 0, "variant": "auto"},
        "noise": {"exposure": exposure},
    }
    return {"sensor": {"exposure_ms": 10.0, "gain": 1.0}, "provenance": {"source": "sim", "scene": scene}}


def test_seeds_threads_and_variant_are_no_setting_but_bounces_and_exposure_are():
    base = capture_settings(_twin_meta())
    assert setting_differences(base, capture_settings(_twin_meta(seed=9))) == []
    assert setting_differences(base, capture_settings(_twin_meta(bounces=2, exposure=0.5))) == [
        "scene.noise.exposure: 1.0 -> 0.5",
        "scene.render.bounces: 1 -> 2",
    ]


def test_the_presses_common_settings_leave_out_what_they_differ_on():
    """A calibration whose presses were rendered at 8 and 16 spp records no spp, so a press at either is not blamed
    on it; what they all share is kept."""
    common = common_settings([capture_settings(_twin_meta(spp=8)), capture_settings(_twin_meta(spp=16))])
    assert "spp" not in common["scene"]["render"] and common["scene"]["render"]["bounces"] == 1
    assert common["exposure_ms"] == 10.0 and common_settings([]) == {}
    assert setting_differences(common, capture_settings(_twin_meta(spp=4)), recorded_only=True) == []
    assert setting_differences(common, capture_settings(_twin_meta(bounces=0)), recorded_only=True) == [
        "scene.render.bounces: 1 -> 0"
    ]
