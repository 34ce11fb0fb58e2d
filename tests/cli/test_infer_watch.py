"""`nlips infer MODEL --watch FOLDER`: frames inferred as a writer drops them into a folder, with the stream's outputs,
its summary on Ctrl-C and SIGTERM, and one line for each bad input.

No timing asserts and no sleeps: the writers start once the watch says it is watching, and the tests wait on files;
a limit (:data:`GIVE_UP_S`) turns a wait that never ends into a failure."""

import signal

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("cv2")
pytest.importorskip("watchdog")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core.imageio import read_png16, write_png16  # noqa: E402

from .watching import drop, main_bounded, tiny_model_frames, watch_until_signalled, writer_once_watching  # noqa: E402


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    """A tiny model of the exact-data sensor and its presses' frames (:func:`.watching.tiny_model_frames`)."""
    return tiny_model_frames(tmp_path_factory, "watch_model")


def test_frames_dropped_while_watching_are_inferred_in_order_and_bad_files_skipped(
    tiny_model, tmp_path, capsys, caplog, monkeypatch
):
    """A writer drops frames (renamed into place, and one written in place), a note, a frame of another size and a
    damaged one while the watch runs: the three good frames are inferred as the predictor infers those files, named
    in frames.tsv, the others each warned about, and --max-frames ends the stream with its summary."""
    from nlipscalib.learn.infer import Predictor

    model, frames = tiny_model
    watched, out = tmp_path / "incoming", tmp_path / "out"
    watched.mkdir()

    def write() -> None:
        drop(watched, "z_first.png", frames[0])
        (watched / "notes.txt").write_text("not a frame", encoding="utf-8")
        write_png16(watched / "small.png", np.full((24, 32, 3), 30000, np.uint16))
        (watched / "cut.png").write_bytes(frames[1].read_bytes()[:200])
        (watched / "b_second.png").write_bytes(frames[1].read_bytes())  # in place: its close says it is whole
        drop(watched, "a_third.png", frames[2])

    thread = writer_once_watching(monkeypatch, write)
    argv = ["--no-progress", "infer", str(model), "--watch", str(watched), "--max-frames", "3", "--out", str(out)]
    code = main_bounded(argv, thread)
    stdout, err = capsys.readouterr()
    assert code == 0, err
    assert stdout == f"{out}\n"
    assert f"watching {watched} for frames as they land" in err and "3 frames in" in err, err
    assert f"saved: 3 of 3 frames' normals and depth in {out}" in err
    assert f"{watched}: 3 file(s) skipped" in err
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    for start in (
        f"{watched / 'notes.txt'}: not an image (.png",
        f"{watched / 'small.png'}: image is 32x24, the model's frames are 64x48; skipped, the watch goes on",
        f"{watched / 'cut.png'}: truncated PNG image",
    ):
        assert any(m.startswith(start) for m in warned), (start, warned)
    order = ["z_first.png", "b_second.png", "a_third.png"]
    assert (out / "frames.tsv").read_text(encoding="utf-8").splitlines() == ["frame\tfile"] + [
        f"frame_{i:06d}\t{name}" for i, name in enumerate(order)
    ]
    predictor = Predictor(model)
    for i, source in enumerate((frames[0], frames[1], frames[2])):
        expected = predictor.predict_stored(read_png16(source))
        saved = np.load(out / f"frame_{i:06d}.npz")
        np.testing.assert_allclose(saved["normals"], expected.normals, atol=1e-4)
        np.testing.assert_allclose(saved["depth"], expected.depth, atol=1e-4)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_ctrl_c_or_sigterm_ends_a_watch_with_its_summary(tiny_model, tmp_path, sig):
    """The watch waits for files for ever: Ctrl-C ends it as it ends any stream (summary, stream.json, exit 0), and
    so does SIGTERM (exit 143 after the summary), though the stream is waiting in the watch, not inferring."""
    model, frames = tiny_model
    watched, out = tmp_path / "incoming", tmp_path / "out"
    watched.mkdir()
    argv = ["--no-progress", "infer", str(model), "--watch", str(watched), "--out", str(out)]
    returncode, err = watch_until_signalled(argv, watched, out, frames[:2], sig)
    assert returncode == (0 if sig == signal.SIGINT else 128 + signal.SIGTERM), err
    assert "2 frames in" in err and f"saved: 2 of 2 frames' normals and depth in {out}" in err, err
    assert (out / "stream.json").is_file() and len(list(out.glob("frame_*.npz"))) == 2
    if sig == signal.SIGTERM:
        assert err.strip().splitlines()[-1].startswith("nlips infer: terminated; the stream stopped"), err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "argv, line",
    [
        (["--watch", "{tmp}/nope"], "--watch {tmp}/nope: no such folder (make it, or name the one the frames are"),
        (["--watch", "{tmp}/a.png"], "--watch {tmp}/a.png: not a folder"),
        (["{tmp}/a.png", "--existing", "infer"], "--existing is for --watch FOLDER"),
        (["{tmp}/a.png", "--poll"], "--poll is for --watch FOLDER"),
        (
            ["--watch", "{tmp}", "--camera", "0"],
            "a stream (a video, --camera, --emulate or --watch) is inferred on its",
        ),
        (["--watch", "{tmp}", "--figures", "full"], "--figures is for press folders and image files"),
    ],
)
def test_bad_watch_arguments_are_one_line_before_the_model_loads(tmp_path, capsys, monkeypatch, argv, line):
    from nlipscalib.cli import _stream

    (tmp_path / "a.png").write_bytes(b"x")
    model = tmp_path / "m.pt"
    model.write_bytes(b"never read: refused before it loads")
    monkeypatch.setattr(_stream, "nlipsnet_predictor", lambda *a, **k: pytest.fail("the model was loaded"))
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(["--no-progress", "infer", str(model), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nlips infer: error: " + line.replace("{tmp}", str(tmp_path))), err
