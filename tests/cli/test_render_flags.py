"""`nlips render` flags refused before anything renders: one line naming the flag and the real bounds."""

import logging

import pytest

from nlipscalib.cli import main


@pytest.mark.parametrize(
    "extra, message",
    [
        # the gel's thickness is the upper bound, stated and checked before "rendering press ..." is logged
        (["--depth", "-1"], "--depth: must be in (0, 3] mm (the scene's gel is 3 mm thick), got -1"),
        (["--depth", "50"], "--depth: must be in (0, 3] mm (the scene's gel is 3 mm thick), got 50"),
        (["--depth", "nan"], "--depth: must be in (0, 3] mm"),
        # the flag typed, not the scene key it sets (was "scene.camera: width: ...")
        (["--width", "100000"], "--width: must be in [8, 16384], got 100000"),
        (["--height", "20000"], "--height: must be in [8, 16384], got 20000"),
        # one side alone kept the scene's other: 160x480 images of a small disc in a black strip, without a word
        (
            ["--width", "160"],
            "--width 160 without --height: the images would be 160x480 pixels (the scene's other side",
        ),
        (["--height", "120"], "--height 120 without --width: the images would be 640x120 pixels"),
        (["--variant", "fast"], "--variant: must be one of ['auto', 'cuda_ad_rgb', 'llvm_ad_rgb', 'scalar_rgb']"),
        # a mistyped word was "press.indenter.kind: must be one of [...]": a key never typed, the choice meant unsaid
        (
            ["--indenter", "sphre"],
            "--indenter: must be one of ['sphere', 'cube', 'cylinder', 'cone', 'screw', 'coin', 'cap', 'gear', 'key', "
            "'brick', 'mesh'], got 'sphre' (did you mean 'sphere'?)\n",
        ),
        (
            ["--indenter", "cube", "--orientation", "cornr"],
            "--orientation: must be one of ['default', 'face', 'edge', 'corner', 'side', 'end'], got 'cornr' (did you "
            "mean 'corner'?)\n",
        ),
        # press options with --undeformed were silently ignored
        (["--undeformed", "--indenter", "coin"], "--indenter is not used with --undeformed: the undeformed dome has"),
        (["--undeformed", "--depth", "2"], "--depth is not used with --undeformed"),
        (["--undeformed", "--press-file", "p.toml"], "--press-file is not used with --undeformed"),
    ],
)
def test_out_of_range_or_inapplicable_flag_is_one_line_before_rendering(tmp_path, capsys, caplog, extra, message):
    caplog.set_level(logging.INFO)
    assert main(["render", *extra, "--out", str(tmp_path / "press")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"nlips render: error: {message}") and err.count("\n") == 1, err
    assert "rendering" not in caplog.text and not (tmp_path / "press").exists()


def test_a_press_file_too_deep_is_named(tmp_path, capsys):
    spec = tmp_path / "deep.toml"
    spec.write_text("depth = 9.0\n", encoding="utf-8")
    assert main(["render", "--press-file", str(spec), "--out", str(tmp_path / "press")]) == 2
    assert (
        capsys.readouterr().err
        == f"nlips render: error: {spec}: depth: must be in (0, 3] mm (the scene's gel is 3 mm thick), got 9\n"
    )
