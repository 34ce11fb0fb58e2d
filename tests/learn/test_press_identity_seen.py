"""Seen or unseen by what was captured (s43-pressid): index.json records each press's identity by content
(core.press_identity), a model keeps those of its presses, and `nlips infer` compares the press or image frame it
reads with them: a copy of a trained press elsewhere with other times in its meta.json is seen, an edited image is
unseen, and a frame of a trained press's tri-colour pixels is seen. Older models and datasets (no content identity)
are judged by the older rule, said once. A re-build over kept shards reads none for index.json's digests. Exact-data
presses, 64x48, no rendering: seconds."""

import hashlib
import json
import logging
import os
import shutil

import cv2
import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import press_identity as identity_module
from nlipscalib.core.imageio import read_png16, write_png16
from nlipscalib.core.press_identity import press_identity
from nlipscalib.learn.dataset import CalibrationDataset, SamplingConfig, build_dataset, write_index, write_shard
from nlipscalib.learn.train import train
from nlipscalib.pipeline import capture_identity
from tests.learn.test_trained_identity import HELD, PRESSES, TINY, VAL, built, solved  # noqa: F401 (fixtures)

torch = pytest.importorskip("torch")

OPTIONS = ["--hidden", "8", "--dropout", "0", "--epochs", "2", "--no-onnx", "--no-progress"]


def _index(folder):
    return json.loads((folder / "index.json").read_text(encoding="utf-8"))


def _report(result):
    return json.loads((result / "report.json").read_text(encoding="utf-8"))


def _restamped(folder):
    """``folder``'s meta.json with another render time, as the same press rendered in another work folder."""
    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    meta["provenance"]["render_seconds"] = 99.5
    (folder / "meta.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
    return folder


def _edited(folder, name):
    image = read_png16(folder / name)
    image[20, 30, 2] ^= 1
    write_png16(folder / name, image)
    return folder


def test_the_index_and_the_model_record_each_press_by_its_content(solved, built, tmp_path):  # noqa: F811
    for entry in _index(built)["presses"]:
        assert entry["press_identity"] == press_identity(solved / entry["name"])
    out = tmp_path / "net.pt"
    train(built, TINY, out, val_names=[VAL], exclude=[HELD], progress=False)
    info = torch.load(out, weights_only=True)["info"]
    assert info["press_identities"] == {name: press_identity(solved / name) for name in PRESSES}


@pytest.fixture
def model(built, tmp_path):  # noqa: F811
    out = tmp_path / "net.pt"
    assert main(["train", str(built), "--out", str(out), "--val-presses", VAL, "--exclude", HELD, *OPTIONS]) == 0
    return out


@pytest.fixture
def inputs(solved, tmp_path):  # noqa: F811
    """Copies of the presses elsewhere: a_sphere and the validation press with other times in their meta.json, b_cube
    with one value of its tri-colour image or of an LED image changed, the held-out press as it is; and image frames
    of a_sphere's tri-colour pixels (its PNG copied, and written again as a TIFF) and of the held-out press's."""
    presses = tmp_path / "presses"
    _restamped(shutil.copytree(solved / "a_sphere", presses / "a_sphere"))
    _restamped(shutil.copytree(solved / VAL, presses / VAL))
    _edited(shutil.copytree(solved / "b_cube", presses / "b_cube_tricolor"), "tricolor.png")
    _edited(shutil.copytree(solved / "b_cube", presses / "b_cube_led"), "led_02.png")
    shutil.copytree(solved / HELD, presses / HELD)
    frames = tmp_path / "frames"
    frames.mkdir()
    shutil.copy(solved / "a_sphere" / "tricolor.png", frames / "frame_a.png")
    bgr = cv2.cvtColor(read_png16(solved / "a_sphere" / "tricolor.png"), cv2.COLOR_RGB2BGR)
    assert cv2.imwrite(str(frames / "frame_a_tiff.tiff"), bgr)
    shutil.copy(solved / HELD / "tricolor.png", frames / "frame_held.png")
    return presses, frames


def _infer(model, presses, frames, out, caplog):
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        argv = ["--no-progress", "infer", str(model), *sorted(map(str, presses.iterdir()))]
        assert main([*argv, "--out", str(out / "p"), "--figures", "none", "--overwrite"]) == 0
        argv = ["--no-progress", "infer", str(model), *sorted(map(str, frames.iterdir()))]
        assert main([*argv, "--out", str(out / "f"), "--figures", "none", "--overwrite"]) == 0
    seen = {p.name: _report(p / "nlipsnet").get("trained_on") for p in (out / "p").iterdir()}
    seen |= {p.name: _report(p).get("trained_on") for p in (out / "f").iterdir()}
    return seen, [r.getMessage() for r in caplog.records if "by their meta.json's bytes too" in r.getMessage()]


def test_a_copy_with_other_times_is_seen_an_edited_one_unseen_and_a_frame_is_told_by_its_pixels(
    solved,  # noqa: F811
    model,
    inputs,
    tmp_path,
    caplog,
):
    assert capture_identity(inputs[0] / "a_sphere") != capture_identity(solved / "a_sphere")  # the older rule's miss
    seen, said = _infer(model, *inputs, tmp_path / "new", caplog)
    assert seen == {
        "a_sphere": "train",
        VAL: "validation",
        "b_cube_tricolor": "unseen",
        "b_cube_led": "unseen",
        HELD: "unseen",
        "frame_a": "train",
        "frame_a_tiff": "train",
        "frame_held": "unseen",
    }
    assert said == []


def test_an_older_model_is_judged_by_meta_json_too_and_says_so_once(model, inputs, tmp_path, caplog):
    """A model trained before 2026-12-08 (no press_identities): the copy with other times counts as unseen, said once
    for the run (two such presses); its frames' results cannot tell (no trained_on)."""
    old = tmp_path / "old.pt"
    payload = torch.load(model, weights_only=True)
    del payload["info"]["press_identities"]
    torch.save(payload, old)
    seen, said = _infer(old, *inputs, tmp_path / "old", caplog)
    assert seen == {
        "a_sphere": "unseen",
        VAL: "unseen",
        "b_cube_tricolor": "unseen",
        "b_cube_led": "unseen",
        HELD: "unseen",
        "frame_a": None,
        "frame_a_tiff": None,
        "frame_held": None,
    }
    assert len(said) == 1 and said[0].startswith(f"{old}: records the presses it learnt from"), said


def test_a_re_run_over_an_older_dataset_records_the_identities_of_its_kept_shards(solved, built, monkeypatch):  # noqa: F811
    """Shards and index.json as a build before 2026-12-08 wrote them (no press_identity): a re-build keeps every
    shard and records each press's identity; the next one takes them from index.json, hashing no press again."""
    index = _index(built)
    for entry in index["presses"]:
        del entry["press_identity"]
        shard = built / "samples" / f"{entry['name']}.npz"
        arrays = {k: v for k, v in dict(np.load(shard)).items() if k != "entry"}
        write_shard(shard, arrays, {k: v for k, v in entry.items() if k != "shard"})
    (built / "index.json").write_text(json.dumps(index), encoding="utf-8")
    assert all("press_identity" not in e for e in CalibrationDataset(built).entries)
    names = [*PRESSES, HELD]
    build_dataset([solved / n for n in names], solved / "reference", built, progress=False)
    for entry in _index(built)["presses"]:
        assert entry["press_identity"] == press_identity(solved / entry["name"])
    monkeypatch.setattr(identity_module, "press_identity", lambda folder: pytest.fail(f"{folder} hashed again"))
    build_dataset([solved / n for n in names], solved / "reference", built, progress=False)  # from index.json now
    for entry in _index(built)["presses"]:
        assert entry["press_identity"] == press_identity(solved / entry["name"])


def test_a_re_build_over_kept_shards_reads_none_for_the_index_and_still_notices_a_changed_one(
    solved,  # noqa: F811
    built,  # noqa: F811
    monkeypatch,
):
    read = []
    digest = hashlib.file_digest

    def counted(f, name):
        if os.path.dirname(f.name) == str(built / "samples"):  # a shard (not a result, an image)
            read.append(os.path.basename(f.name))
        return digest(f, name)

    monkeypatch.setattr(hashlib, "file_digest", counted)
    names = [*PRESSES, HELD]
    before = _index(built)
    build_dataset([solved / n for n in names], solved / "reference", built, progress=False)
    assert read == []  # no shard read for its digest
    assert [e["shard"] for e in _index(built)["presses"]] == [e["shard"] for e in before["presses"]]

    changed, touched = built / "samples" / "a_sphere.npz", built / "samples" / "b_cube.npz"
    arrays = dict(np.load(changed))
    arrays["rgb"][0, 0] += 0.01  # its samples written again (a new file), its time kept
    stat = changed.stat()
    write_shard(changed, {k: v for k, v in arrays.items() if k != "entry"}, json.loads(arrays["entry"].tobytes()))
    os.utime(changed, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    stat = touched.stat()
    data = bytearray(touched.read_bytes())
    data[-30] ^= 0xFF  # in place (the zip directory's end: the shard still reads), its size and time kept
    touched.write_bytes(bytes(data))
    os.utime(touched, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    read.clear()
    entries = [{k: v for k, v in e.items() if k != "shard"} for e in _index(built)["presses"]]  # written again
    write_index(built, _index(built)["sensor"], SamplingConfig(), entries, str(solved / "reference"))
    assert sorted(read) == ["a_sphere.npz", "b_cube.npz"]  # the two changed ones alone
    records = {e["name"]: e["shard"] for e in _index(built)["presses"]}
    for shard in (changed, touched):
        assert records[shard.stem]["sha256"] == hashlib.sha256(shard.read_bytes()).hexdigest()
    assert CalibrationDataset(built).samples_changed(names) is None


def test_a_reused_model_without_press_identities_is_said_of(model, built, tmp_path, caplog):  # noqa: F811
    """`nlips train` re-run with the same options reuses the model; one trained before 2026-12-08 (no
    press_identities) is reused with one warning of what its verdicts miss; this version's without."""
    args = ["train", str(built), "--out", str(model), "--val-presses", VAL, "--exclude", HELD, *OPTIONS]
    with caplog.at_level(logging.WARNING):
        assert main(args) == 0
    assert not [r for r in caplog.records if "meta.json's bytes too" in r.getMessage()]
    payload = torch.load(model, weights_only=True)
    del payload["info"]["press_identities"]
    torch.save(payload, model)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert main(args) == 0
    warned = [r.getMessage() for r in caplog.records if "meta.json's bytes too" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith(f"{model}: trained before 2026-12-08"), warned


def test_the_rule_by_content_first_then_by_meta_json():
    """learn.seen.trained_on on records alone: a content match names the split; no match with every press recorded is
    unseen; with a press unrecorded (a dataset of before) the older rule decides, and cannot tell a non-match."""
    from nlipscalib.learn.seen import judged_by_meta, trained_on

    def ident(c):
        return {"rule": 1, "press": c * 64, "tricolor": c.upper() * 64}

    info = {
        "captures": {"a": "1" * 64, "b": "2" * 64},
        "press_identities": {"a": ident("a"), "b": ident("b")},
        "val_presses": ["b"],
    }
    old_inputs = {"press": "9" * 64}  # another meta.json: the older rule misses it
    assert trained_on(info, old_inputs, ident("a")) == "train"
    assert trained_on(info, old_inputs, ident("b")) == "validation"
    assert trained_on(info, old_inputs, ident("c")) == "unseen" and not judged_by_meta(info, ident("c"))
    frame = {"rule": 1, "tricolor": "B" * 64}
    assert trained_on(info, {"frame": "f" * 64}, frame) == "validation"
    assert trained_on(info, {"frame": "f" * 64}, {"rule": 1, "tricolor": "C" * 64}) == "unseen"
    assert trained_on(info, old_inputs, ident("a") | {"rule": 2}) == "unseen"  # another rule: by meta.json's bytes
    partial = info | {"press_identities": {"a": ident("a"), "b": None}}
    assert trained_on(partial, old_inputs, ident("a")) == "train"
    assert trained_on(partial, {"press": "2" * 64}, ident("c")) == "validation"  # the older rule's match
    assert trained_on(partial, old_inputs, ident("c")) == "unseen" and judged_by_meta(partial, ident("c"))
    assert trained_on(partial | {"captures": {"a": "1" * 64, "b": None}}, old_inputs, ident("c")) is None
    assert trained_on({"captures": info["captures"]}, {"frame": "f" * 64}, frame) is None  # a frame, an older model
