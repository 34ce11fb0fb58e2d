"""`nlips live --watch FOLDER`: the live view of frames a writer drops into a folder (the watched-folder source of
`nlips infer --watch`), warnings naming each frame's file, its end on --max-frames, Ctrl-C and SIGTERM, and one line
for each bad input.

No timing asserts and no sleeps: the writers start once the watch says it is watching, and the tests wait on files;
a limit (:data:`GIVE_UP_S`) turns a wait that never ends into a failure."""

import signal

import numpy as np
import pytest

pytest.importorskip("cv2")
pytest.importorskip("watchdog")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core.imageio import read_png16  # noqa: E402

from .watching import drop, main_bounded, tiny_model_frames, watch_until_signalled, writer_once_watching  # noqa: E402

FLAT = "tests.device.fakes:flat_predictor"


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    """A tiny model of the exact-data sensor and its presses' frames (:func:`.watching.tiny_model_frames`)."""
    pytest.importorskip("torch")
    return tiny_model_frames(tmp_path_factory, "live_watch_model")


def test_live_shows_the_frames_dropped_into_a_watched_folder_and_warnings_name_their_files(
    tiny_model, tmp_path, capsys, caplog, monkeypatch
):
    """A writer drops two frames of the sensor, a black one (unlike the calibration's reference) and one of another
    size while `nlips live --model --watch` runs: the three of the model's size are streamed as the predictor infers
    those files, the black one warned about by its file (not "FOLDER frame 1"), the small one skipped and counted;
    --max-frames ends it with its summary and frames.tsv names each saved frame's file."""
    from nlipscalib.learn.infer import Predictor

    model, frames = tiny_model
    watched, out = tmp_path / "incoming", tmp_path / "out"
    watched.mkdir()

    def write() -> None:
        drop(watched, "z_first.png", frames[0])
        drop(watched, "small.png", np.full((24, 32, 3), 30000, np.uint16))
        drop(watched, "black.png", np.zeros((48, 64, 3), np.uint16))
        drop(watched, "a_last.png", frames[1])

    thread = writer_once_watching(monkeypatch, write)
    argv = ["--no-progress", "live", "--model", str(model), "--watch", str(watched), "--no-window"]
    code = main_bounded([*argv, "--max-frames", "3", "--out", str(out)], thread)
    stdout, err = capsys.readouterr()
    assert code == 0, err
    assert stdout == f"{out}\n"
    assert f"watching {watched} for frames as they land" in err and "3 frames in" in err, err
    assert f"saved: 3 of 3 frames' normals and depth in {out}" in err
    assert f"{watched}: 1 file(s) skipped" in err
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    black = f"{watched / 'black.png'}: differs from the calibration's reference frame over most of the gel"
    assert any(m.startswith(black) for m in warned), warned
    assert not any(f"{watched} frame" in m for m in warned), warned
    assert any(m.startswith(f"{watched / 'small.png'}: image is 32x24, the model's frames are 64x48") for m in warned)
    assert any(m.startswith("1 of 3 frames differed from the calibration's reference") for m in warned), warned
    names = ["z_first.png", "black.png", "a_last.png"]
    assert (out / "frames.tsv").read_text(encoding="utf-8").splitlines() == ["frame\tfile"] + [
        f"frame_{i:06d}\t{name}" for i, name in enumerate(names)
    ]
    predictor = Predictor(model)
    for i, source in ((0, frames[0]), (2, frames[1])):
        expected = predictor.predict_stored(read_png16(source))
        saved = np.load(out / f"frame_{i:06d}.npz")
        np.testing.assert_allclose(saved["normals"], expected.normals, atol=1e-4)
        np.testing.assert_allclose(saved["depth"], expected.depth, atol=1e-4)


def test_infer_names_a_watched_frame_unlike_the_reference_by_its_file(
    tiny_model, tmp_path, capsys, caplog, monkeypatch
):
    """`nlips infer --watch` warns as `nlips live --watch` does: the file a user can open, not "FOLDER frame 0"."""
    model, _ = tiny_model
    watched = tmp_path / "incoming"
    watched.mkdir()
    thread = writer_once_watching(monkeypatch, lambda: drop(watched, "dark.png", np.zeros((48, 64, 3), np.uint16)))
    code = main_bounded(["--no-progress", "infer", str(model), "--watch", str(watched), "--max-frames", "1"], thread)
    err = capsys.readouterr().err
    assert code == 0, err
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert any(m.startswith(f"{watched / 'dark.png'}: differs from the calibration's reference") for m in warned)
    assert not any(f"{watched} frame" in m for m in warned), warned


def test_a_plugged_predictor_on_a_watched_folder_takes_the_first_frames_size(tmp_path, capsys, caplog, monkeypatch):
    """`--predictor` has no model to give the frames' size: the first file sets it, and the predictor is made for it;
    a later file of another size is skipped, naming the first."""
    watched, out = tmp_path / "incoming", tmp_path / "out"
    watched.mkdir()

    def write() -> None:
        drop(watched, "one.png", np.full((12, 16, 3), 1000, np.uint16))
        drop(watched, "wide.png", np.full((12, 20, 3), 9000, np.uint16))
        drop(watched, "two.png", np.full((12, 16, 3), 3000, np.uint16))

    thread = writer_once_watching(monkeypatch, write)
    argv = ["--no-progress", "live", "--predictor", FLAT, "--watch", str(watched), "--no-window", "--max-frames", "2"]
    code = main_bounded([*argv, "--out", str(out)], thread)
    err = capsys.readouterr().err
    assert code == 0, err
    depth = [float(np.load(out / f"frame_{i:06d}.npz")["depth"][0, 0]) for i in range(2)]
    assert depth == pytest.approx([1.0, 3.0])  # flat_predictor: the mean green value / 1000
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    wide = f"{watched / 'wide.png'}: image is 20x12, the stream's first frame (one.png) is 16x12; skipped"
    assert any(m.startswith(wide) for m in warned), warned


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_ctrl_c_or_sigterm_ends_a_live_watch_with_its_summary(tmp_path, sig):
    """The watch waits for files for ever: Ctrl-C ends it with the summary (exit 0), and so does SIGTERM (exit 143
    after the summary), though the stream waits for a file, not inferring."""
    watched, out = tmp_path / "incoming", tmp_path / "out"
    watched.mkdir()
    argv = ["--no-progress", "live", "--predictor", FLAT, "--watch", str(watched), "--no-window", "--out", str(out)]
    frames = [np.full((12, 16, 3), 1000 * (i + 1), np.uint16) for i in range(2)]
    returncode, err = watch_until_signalled(argv, watched, out, frames, sig)
    assert returncode == (0 if sig == signal.SIGINT else 128 + signal.SIGTERM), err
    assert "2 frames in" in err and f"saved: 2 of 2 frames' normals and depth in {out}" in err, err
    if sig == signal.SIGTERM:
        assert err.strip().splitlines()[-1].startswith("nlips live: terminated; the stream stopped"), err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "argv, line",
    [
        (["--watch", "{tmp}/nope"], "--watch {tmp}/nope: no such folder (make it, or name the one the frames are"),
        (["--watch", "{tmp}/a.png"], "--watch {tmp}/a.png: not a folder (--watch takes the folder the frames"),
        (["--watch", "{tmp}", "--camera", "0"], "--watch {tmp} and --camera 0 are two sources of frames: give one"),
        (["--watch", "{tmp}", "--emulate", "nlipstac"], "--watch {tmp} and --emulate nlipstac are two sources of"),
        (["--camera", "{tmp}", "--existing", "infer"], "--existing is for --watch FOLDER"),
        (["--camera", "{tmp}", "--poll"], "--poll is for --watch FOLDER"),
        (["--watch", "{tmp}", "--exposure-ms", "5"], "--exposure-ms sets a live camera's exposure"),
    ],
)
def test_bad_watch_arguments_of_live_are_one_line_before_the_model_loads(tmp_path, capsys, monkeypatch, argv, line):
    from nlipscalib.cli import live

    (tmp_path / "a.png").write_bytes(b"x")
    model = tmp_path / "m.pt"
    model.write_bytes(b"never read: refused before it loads")
    monkeypatch.setattr(live, "nlipsnet_predictor", lambda *a, **k: pytest.fail("the model was loaded"))
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(["--no-progress", "live", "--model", str(model), "--no-window", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nlips live: error: " + line.replace("{tmp}", str(tmp_path))), err
