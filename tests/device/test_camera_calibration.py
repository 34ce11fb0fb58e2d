"""Camera calibration recovers a known fisheye camera from checkerboard views rendered with the core model."""

import re

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from nlipscalib.core import Camera  # noqa: E402
from nlipscalib.core.errors import CaptureError  # noqa: E402
from nlipscalib.device.camera_calibration import (  # noqa: E402
    Target,
    board_points,
    calibrate,
    calibrate_images,
    find_corners,
)

PATTERN, SQUARE = (8, 6), 3.0
TRUE = Camera.from_fov(320, 240, 110.0, "fisheye", (0.06, -0.02, 0.004, -0.001))
RAMP_MM = 0.2
SUPER = 4  # supersamples per pixel side: antialiased edges give sub-pixel corners


def _rotation(rx, ry, rz):
    return cv2.Rodrigues(np.radians([rx, ry, rz]))[0]


@pytest.fixture(scope="module")
def subpixel_rays():
    """Viewing rays of a SUPER x SUPER grid inside every pixel, (H*S, W*S, 3), from the true camera."""
    h, w = TRUE.shape
    offs = (np.arange(SUPER) + 0.5) / SUPER - 0.5
    u = (np.arange(w)[:, None] + offs).ravel()
    v = (np.arange(h)[:, None] + offs).ravel()
    uu, vv = np.meshgrid(u, v)
    return TRUE.unproject(np.stack([uu, vv], -1))


def render_board(rays, R, t):
    """8-bit image of the checkerboard (inner corners at board_points) seen through the true camera."""
    n, c = R[:, 2], np.asarray(t, float)
    lam = (n @ c) / (rays @ n)
    local = (lam[..., None] * rays - c) @ R  # board frame
    x, y = local[..., 0] / SQUARE, local[..., 1] / SQUARE
    cols, rows = PATTERN
    # a soft edge (a ramp RAMP_MM wide, like a lens's blur) keeps the edges' sub-pixel position in the
    # pixel values; with hard edges the supersampling would quantise it to 1/SUPER pixel
    k = SQUARE / (np.pi * RAMP_MM)
    checker = np.clip(k * np.sin(np.pi * x), -1, 1) * np.clip(k * np.sin(np.pi * y), -1, 1)  # > 0: dark
    board = (x >= -1) & (x < cols) & (y >= -1) & (y < rows)
    margin = (x >= -2) & (x < cols + 1) & (y >= -2) & (y < rows + 1)
    value = np.where(board, 127.5 - 107.5 * checker, np.where(margin, 235.0, 120.0))
    value[lam <= 0] = 120.0
    h, w = TRUE.shape
    value = value.reshape(h, SUPER, w, SUPER).mean(axis=(1, 3))
    return np.clip(np.rint(value), 0, 255).astype(np.uint8)


POSES = [  # (rotation degrees, board centre in the camera frame, mm): boards spread over the whole field
    ((0, 0, 0), (0, 0, 24)),
    ((20, 0, 5), (0, 0, 22)),
    ((-20, 20, 0), (0, 0, 22)),
    ((0, 30, 0), (-14, 0, 24)),
    ((0, -30, 0), (14, 0, 24)),
    ((25, 0, 0), (0, -10, 24)),
    ((-25, 0, 0), (0, 10, 24)),
    ((10, 25, 10), (-9, -6, 26)),
    ((-10, -25, -10), (9, 6, 26)),
    ((15, -25, 0), (9, -6, 26)),
    ((-15, 25, 5), (-9, 6, 26)),
    ((0, 0, 30), (0, 0, 28)),
]


def _pose(rotation_deg, centre):
    """(R, t) placing the board's centre at ``centre``."""
    R = _rotation(*rotation_deg)
    mid = np.array([(PATTERN[0] - 1) / 2 * SQUARE, (PATTERN[1] - 1) / 2 * SQUARE, 0.0])
    return R, np.asarray(centre, float) - R @ mid


@pytest.fixture(scope="module")
def views(subpixel_rays):
    return [render_board(subpixel_rays, *_pose(r, c)) for r, c in POSES]


def test_recovers_the_known_fisheye_camera(views, tmp_path):
    target = Target(PATTERN, SQUARE)
    detected = [target.detect(v) for v in views]
    assert sum(d is not None for d in detected) >= 8
    cal = calibrate(detected, (TRUE.width, TRUE.height), "fisheye")
    assert cal.rms_px < 0.1, cal.per_view_px
    assert cal.camera.model == "fisheye"
    assert cal.camera.fx == pytest.approx(TRUE.fx, rel=0.01) and cal.camera.cx == pytest.approx(TRUE.cx, abs=0.5)
    # the recovered lens maps the field the boards covered like the true one: within 0.3 px
    board_rays = np.concatenate([board_points(PATTERN, SQUARE) @ _pose(r, c)[0].T + _pose(r, c)[1] for r, c in POSES])
    covered = np.arccos(board_rays[:, 2] / np.linalg.norm(board_rays, axis=1)).max()
    uv = np.stack(np.meshgrid(np.linspace(0, 319, 33), np.linspace(0, 239, 25)), -1).reshape(-1, 2)
    rays = TRUE.unproject(uv)
    inside = np.arccos(rays[:, 2]) <= covered
    assert inside.mean() > 0.5
    np.testing.assert_allclose(cal.camera.project(rays[inside]), uv[inside], atol=0.3)
    # the same through files, as `nlips calibrate-camera` reads them
    paths = []
    for k, v in enumerate(views):
        paths.append(tmp_path / f"view_{k:02d}.png")
        cv2.imwrite(str(paths[-1]), v)
    from_files = calibrate_images(paths, target)
    assert from_files.rms_px == pytest.approx(cal.rms_px, rel=1e-6)


def test_board_points_follow_opencv_order():
    pts = board_points((3, 2), 2.0)
    assert pts.tolist()[:4] == [[0, 0, 0], [2, 0, 0], [4, 0, 0], [0, 2, 0]]


def test_too_few_views_is_a_clear_error():
    blank = np.full((60, 80), 128, np.uint8)
    assert find_corners(blank, PATTERN) is None
    with pytest.raises(CaptureError, match=r"found in 0 of 2 images; at least 3 are needed \(check --pattern"):
        calibrate([None, None], (80, 60))


def test_too_few_views_in_a_folder_name_the_folder(tmp_path, capsys):
    """`nlips calibrate-camera frames --pattern 8x6 ...` on images without the board said "the 8x6 checkerboard was
    found in 0 of 6 images ..." without naming where the images came from."""
    from nlipscalib.cli import main

    shots = tmp_path / "shots"
    shots.mkdir()
    for k in range(2):
        cv2.imwrite(str(shots / f"v{k}.png"), np.full((60, 80), 128, np.uint8))
    assert (
        main(["calibrate-camera", str(shots), "--pattern", "8x6", "--square", "3", "--out", str(tmp_path / "c.json")])
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{shots}: the 8x6 checkerboard was found in 0 of 2 images" in err[0], err


def test_too_few_images_each_showing_the_board_asks_for_more_not_for_another_pattern(views):
    """`nlips calibrate-camera one.png` (the board found in 1 of 1 images) was told to check --pattern."""
    detected = Target(PATTERN, SQUARE).detect(views[0])
    assert detected is not None
    with pytest.raises(CaptureError) as err:
        calibrate([detected], (TRUE.width, TRUE.height))
    assert str(err.value).endswith(
        "found in 1 of 1 images; at least 3 are needed (take more pictures of it, in different poses over the whole "
        "image)"
    )
    assert "--pattern" not in str(err.value)


def test_cli_writes_the_camera_block(views, tmp_path, capsys):
    import json

    from nlipscalib.cli import main

    for k, v in enumerate(views[:6]):
        cv2.imwrite(str(tmp_path / f"v{k}.png"), v)
    cv2.imwrite(str(tmp_path / "blank.png"), np.full((240, 320), 128, np.uint8))
    out = tmp_path / "camera.json"
    args = ["calibrate-camera", str(tmp_path), "--pattern", "8x6", "--square", "3", "--out", str(out)]
    assert main(args) == 0
    said = capsys.readouterr()  # stdout: the camera file alone; the fit's figures, on stderr
    assert said.out == f"{out}\n"
    text = said.err
    assert "blank.png: board not found" in text and "reprojection error" in text
    # the lens line is legible: four significant digits per coefficient, not a tuple of full float reprs
    lens = next(line for line in text.splitlines() if line.startswith("fisheye camera"))
    assert "dist " in lens and "(" not in lens and not re.search(r"\.\d{7}", lens), lens
    data = json.loads(out.read_text(encoding="utf-8"))
    assert Camera.from_dict(data["camera"]).model == "fisheye" and data["reprojection_rms_px"] < 0.1
    assert main(args[:3] + ["9x6"] + args[4:]) == 2  # wrong pattern: one clear error, no traceback
    assert "found in 0 of 7 images" in capsys.readouterr().err
    # the same folder twice counts each view once; an empty folder, a folder as --out, --square -3: one line each
    assert main(args[:2] + [str(tmp_path)] + args[2:]) == 0
    assert "(RMS over 6 views)" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    for bad, message in (
        ([args[0], str(tmp_path / "empty"), *args[2:]], "empty: no images (.bmp"),
        ([*args[:-1], str(tmp_path)], "a folder; give the JSON file to write"),
        # a folder meant, not there yet: the camera file was written as that name
        ([*args[:-1], f"{tmp_path / 'cams'}/"], f"a folder; give the JSON file to write (e.g. {tmp_path / 'cams'}/"),
        ([*args[:5], "-3", *args[6:]], "--square must be > 0 mm, got -3.0"),
    ):
        assert main(bad) == 2
        assert message in capsys.readouterr().err


CHARUCO = Target((5, 4), 6.0, marker_mm=4.5, dictionary="DICT_4X4_50")


def render_charuco(rays, R, t, texels_per_square=64):
    """8-bit image of the ChArUco board (OpenCV's own drawing, slightly blurred like a lens) through the true camera."""
    from nlipscalib.device.camera_calibration import charuco_board

    cols, rows = CHARUCO.pattern
    texture = charuco_board(CHARUCO).generateImage((cols * texels_per_square, rows * texels_per_square), marginSize=0)
    texture = cv2.GaussianBlur(texture.astype(np.float32), (0, 0), texels_per_square / 40) * (215 / 255) + 20
    n, c = R[:, 2], np.asarray(t, float)
    lam = (n @ c) / (rays @ n)
    local = (lam[..., None] * rays - c) @ R  # board frame, mm; OpenCV's board: x right, y down from its corner
    scale = texels_per_square / CHARUCO.square_mm
    mapx = np.where(lam > 0, local[..., 0] * scale - 0.5, -1e6).astype(np.float32)
    mapy = np.where(lam > 0, local[..., 1] * scale - 0.5, -1e6).astype(np.float32)
    value = cv2.remap(texture, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=235.0)
    h, w = TRUE.shape
    return np.clip(np.rint(value.reshape(h, SUPER, w, SUPER).mean(axis=(1, 3))), 0, 255).astype(np.uint8)


def _charuco_pose(rotation_deg, centre):
    R = _rotation(*rotation_deg)
    mid = np.array([CHARUCO.pattern[0] / 2 * CHARUCO.square_mm, CHARUCO.pattern[1] / 2 * CHARUCO.square_mm, 0.0])
    return R, np.asarray(centre, float) - R @ mid


def test_charuco_calibration_uses_partial_views(subpixel_rays):
    poses = POSES + [((0, 0, 0), (-20, 0, 20)), ((0, 0, 0), (20, 0, 20))]  # the last two: board partly outside
    views = [render_charuco(subpixel_rays, *_charuco_pose(r, c)) for r, c in poses]
    detected = [CHARUCO.detect(v) for v in views]
    assert sum(d is not None for d in detected) >= 10
    partial = [d for d in detected[-2:] if d is not None]
    assert partial and all(len(d[0]) < 12 for d in partial)  # fewer than all 4x3 inner corners seen
    cal = calibrate(detected, (TRUE.width, TRUE.height), "fisheye", target_name=CHARUCO.name)
    assert cal.rms_px < 0.2, cal.per_view_px
    assert cal.camera.fx == pytest.approx(TRUE.fx, rel=0.01)


def test_views_of_one_orientation_are_refused(subpixel_rays):
    """Four shots of a board that was not moved, or boards all facing the camera: any focal length fits them
    (the fit wrote fx 2944 px for a 640 px camera at 0.7 px error); one clear error instead."""
    target = Target(PATTERN, SQUARE)
    same = [target.detect(render_board(subpixel_rays, *_pose((20, 0, 5), (0, 0, 22))))] * 4
    facing = [
        target.detect(render_board(subpixel_rays, *_pose((0, 0, 0), c))) for c in [(0, 0, 22), (-6, 0, 26), (6, 3, 30)]
    ]
    for detected in (same, facing):
        assert all(d is not None for d in detected)
        with pytest.raises(
            CaptureError, match="does not pin the camera down .* tilted 20-40 deg in different directions"
        ):
            calibrate(detected, (TRUE.width, TRUE.height), "fisheye", target_name=target.name)


def test_a_poor_fit_is_written_with_a_warning(views, tmp_path, capsys, caplog):
    """Views the model cannot explain (half of them sheared, as a bent board or a wrong lens model would)."""
    from nlipscalib.cli import main

    for k, v in enumerate(views):
        shear = np.float32([[1, 0.2 * (k % 2), 0], [0, 1, 0]])
        cv2.imwrite(str(tmp_path / f"v{k:02d}.png"), cv2.warpAffine(v, shear, v.shape[::-1], borderValue=120))
    args = ["calibrate-camera", str(tmp_path), "--pattern", "8x6", "--square", "3", "--out", str(tmp_path / "c.json")]
    assert main(args) == 0 and (tmp_path / "c.json").is_file()
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1 and "is high (a good calibration is below 1 px)" in warnings[0], warnings
    assert int(warnings[0].split("worst view: v")[1][:2]) % 2 == 1  # a sheared one
    caplog.clear()
    for k, v in enumerate(views):  # the same views unsheared: no warning
        cv2.imwrite(str(tmp_path / f"v{k:02d}.png"), v)
    assert main(args) == 0 and not [r for r in caplog.records if r.levelname == "WARNING"]
