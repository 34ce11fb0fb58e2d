import json

import numpy as np

from nlipscalib.cli import main
from nlipscalib.core.reconstruction import load_reconstruction


def test_solve_eval_calibrate_cli(presses, tmp_path, capsys):
    import shutil

    press = tmp_path / "set" / "sphere"
    shutil.copytree(presses["sphere"], press)
    cfg = tmp_path / "solver.toml"
    cfg.write_text("max_iters = 5\n", encoding="utf-8")
    assert main(["solve", str(press), "--config", str(cfg)]) == 0
    out = press / "nlips"
    for name in ("result.npz", "report.json", "normals.png", "depth.png", "residual.png", "error.png"):
        assert (out / name).is_file(), name
    stamp = (out / "result.npz").stat().st_mtime_ns
    assert main(["solve", str(press), "--config", str(cfg)]) == 0  # resumable: skipped
    assert (out / "result.npz").stat().st_mtime_ns == stamp
    capsys.readouterr()
    assert main(["eval", str(tmp_path / "set")]) == 0
    table = capsys.readouterr().out
    assert "AAE" in table and "sphere" in table
    leds = tmp_path / "leds.json"
    assert main(["calibrate-leds", str(presses["none"]), "--out", str(leds), "--stride", "4"]) == 0
    assert len(json.loads(leds.read_text(encoding="utf-8"))["leds"]) == 12
    assert (
        main(
            [
                "solve",
                str(press),
                "--leds",
                str(leds),
                "--overwrite",
                "--config",
                str(cfg),
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 0
    )
    assert np.isfinite(load_reconstruction(tmp_path / "o").normals).all()
    assert main(["solve", str(press), "--roi", "1", "2"]) == 2


def test_led_file_of_another_sensor_is_refused(presses, tmp_path, capsys, caplog):
    """An LED file records the sensor it was calibrated on; `solve --leds` refuses it for another sensor's
    press (same camera and LED count, LEDs 1.5 mm away: the twin's fingertip against NLiPsTac), and warns
    about a file that records no sensor when its LEDs are far from the capture's."""
    import shutil

    leds = tmp_path / "leds.json"
    assert main(["calibrate-leds", str(presses["none"]), "--out", str(leds), "--stride", "8"]) == 0
    assert json.loads(leds.read_text(encoding="utf-8"))["sensor"]["n_leds"] == 12
    other = tmp_path / "other"
    shutil.copytree(presses["sphere"], other)
    meta = json.loads((other / "meta.json").read_text(encoding="utf-8"))
    for led in meta["leds"]:
        led["position"] = [v * 1.2 for v in led["position"]]
    (other / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    capsys.readouterr()
    assert main(["solve", str(other), "--leds", str(leds)]) == 2
    err = capsys.readouterr().err
    assert f"{leds}: calibrated on another sensor than {other}" in err and "LED 1 is" in err
    assert "Traceback" not in err and not (other / "nlips").exists()

    # a session captured with these calibrated LEDs records them in meta.json, not the design: accepted
    captured = tmp_path / "captured"
    shutil.copytree(presses["sphere"], captured)
    meta = json.loads((captured / "meta.json").read_text(encoding="utf-8"))
    meta["leds"] = [
        {**d, "position": [v * 1.2 for v in d["position"]]}
        for d in json.loads(leds.read_text(encoding="utf-8"))["leds"]
    ]
    (captured / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    good = json.loads(leds.read_text(encoding="utf-8"))
    good["leds"] = meta["leds"]
    leds_moved = tmp_path / "leds_moved.json"  # its LEDs 20 % further out than the design it records
    leds_moved.write_text(json.dumps(good), encoding="utf-8")
    cfg = tmp_path / "solver.toml"
    cfg.write_text("max_iters = 2\n", encoding="utf-8")
    assert main(["solve", str(captured), "--leds", str(leds_moved), "--roi", "40,30,24,24", "--config", str(cfg)]) == 0

    unrecorded = json.loads(leds.read_text(encoding="utf-8"))
    del unrecorded["sensor"]
    leds.write_text(json.dumps(unrecorded), encoding="utf-8")
    assert main(["solve", str(other), "--leds", str(leds), "--roi", "40,30,24,24", "--config", str(cfg)]) == 0
    assert "records no sensor to check against" in caplog.text


def test_a_stride_that_leaves_too_few_pixels_is_refused(presses, tmp_path, capsys):
    """--stride 10000 kept one pixel: half the LEDs came out NaN, the fit called itself reliable, exit 0."""
    out = tmp_path / "leds.json"
    assert main(["calibrate-leds", str(presses["none"]), "--out", str(out), "--stride", "10000"]) == 2
    err = capsys.readouterr().err
    assert "stride 10000 leaves 1 pixels of the gel" in err and "smaller stride" in err and not out.exists()


def test_calibrate_leds_names_its_worst_led_beside_the_median_that_decides():
    """One LED fitted far worse than the others is hidden by the median of 12: the fit's line names it."""
    from nlipscalib.cli.calibrate import _fit_line

    ratios = [0.8] * 12
    ratios[2] = 2.1
    line = _fit_line({"ratio": ratios, "median_ratio": 0.8, "threshold": 1.15, "reliable": True})
    assert line.startswith("fit: residual 0.80x") and "worst LED 3 2.10x" in line and line.endswith(": reliable")


def test_a_capture_recording_a_bad_led_size_is_refused_in_one_line_before_the_fit(presses, tmp_path, capsys):
    """A meta.json whose design declares an LED emitting diameter that is no size (s29-ledsize: the default LED
    model comes from it) is named with the key, exit 2, no file; --led-diameter overrides the design's word."""
    import shutil

    capture = tmp_path / "none"
    shutil.copytree(presses["none"], capture)
    meta = json.loads((capture / "meta.json").read_text(encoding="utf-8"))
    meta["design"] = {"leds": {"emitter_diameter": -3.6}}
    (capture / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    out = tmp_path / "leds.json"
    assert main(["calibrate-leds", str(capture), "--out", str(out), "--stride", "4"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{capture / 'meta.json'}: design.leds.emitter_diameter: must be in [0.0, 20.0], got -3.6" in line
    assert not out.exists()
    assert main(["calibrate-leds", str(capture), "--out", str(out), "--stride", "4", "--led-diameter", "0"]) == 0
    assert json.loads(out.read_text(encoding="utf-8"))["led_model"]["from"] == "--led-diameter"


def test_runs_at_once_into_one_led_file_fit_it_once_and_another_fit_is_refused(
    presses, tmp_path, monkeypatch, capsys, caplog
):
    """Three `nlips calibrate-leds` at once into one --out each fitted the same LEDs and wrote the file in turn (whole
    each time: the last one's left), and a run of other captures or options replaced the other's file unsaid. Now
    the file is claimed (core.claims) while it is fitted and written: a run of the same fit waits and keeps what the
    other wrote (or fits when it wrote nothing: killed, failed); another fit is refused in one line. A thread
    holding the claim stands for the other process here."""
    import logging
    import threading
    import time

    from nlipscalib import solver
    from nlipscalib.cli import build_parser
    from nlipscalib.cli.calibrate import _fit_key
    from nlipscalib.core import claims

    monkeypatch.setattr(claims, "CLAIM_POLL_S", 0.05)
    caplog.set_level(logging.INFO, logger="nlipscalib")
    out = tmp_path / "leds.json"
    argv = ["calibrate-leds", str(presses["none"]), "--out", str(out), "--stride", "8"]
    assert main(argv) == 0
    whole = out.read_bytes()
    out.unlink()
    key = _fit_key(build_parser().parse_args(argv))
    released = []

    def other_run(its_key: str, write: bool) -> threading.Thread:
        held = threading.Event()

        def run() -> None:
            with claims.claim(out, note={"key": its_key}) as mine:
                assert mine
                held.set()
                time.sleep(0.5)
                if write:
                    out.write_bytes(whole)
                released.append(time.time())

        thread = threading.Thread(target=run)
        thread.start()
        held.wait(5)
        return thread

    fits = []
    fit = solver.calibrate_leds
    monkeypatch.setattr(solver, "calibrate_leds", lambda *a, **k: fits.append(1) or fit(*a, **k))
    capsys.readouterr()
    thread = other_run(key, write=True)
    assert main(argv) == 0
    thread.join()
    captured = capsys.readouterr()  # stdout: the file, the other run's; whose it is, on stderr
    assert captured.out == f"{out}\n"
    said = captured.err.strip().splitlines()
    assert said[-1].startswith(f"{out}: written by process ") and "nothing to do" in said[-1], said
    assert fits == [] and out.read_bytes() == whole and "is fitting the same LEDs" in caplog.text

    thread = other_run("another", write=True)
    assert main(argv) == 2
    thread.join()
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{out}: process " in line and "from other captures or options; wait until it ends" in line, line
    assert fits == []

    out.unlink()
    thread = other_run(key, write=False)  # the other run ends without the file: this one fits, after it
    assert main(argv) == 0
    thread.join()
    assert fits == [1] and out.stat().st_mtime >= released[-1]
