"""A small digital-twin calibration set, shared by the learn tests (session scope, ~1 min on 2 cores).

96x72 images of the default NLiPsTac scene, 1 spp, direct light only, sensor noise on; seven presses
(spheres, cubes and cylinders at different places and depths) plus the undeformed reference, all
solved with NLiPs and turned into a calibration dataset.
"""

import pytest

pytest.importorskip("mitsuba")
pytest.importorskip("torch")

from nlipscalib.sim.indent import PressConfig  # noqa: E402
from nlipscalib.sim.indenters import IndenterConfig  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402

WIDTH, HEIGHT = 96, 72
SPHERE, CUBE, CYL = (
    IndenterConfig(kind="sphere", size=6.0),
    IndenterConfig(kind="cube", size=5.0),
    IndenterConfig(kind="cylinder", size=5.0),
)
PRESSES = {
    "press_a": PressConfig(SPHERE, polar_deg=12, azimuth_deg=30, depth=1.3),
    "press_b": PressConfig(CUBE, polar_deg=15, azimuth_deg=200, depth=1.1),
    "press_c": PressConfig(CYL, polar_deg=8, azimuth_deg=110, depth=1.2),
    "press_d": PressConfig(SPHERE, polar_deg=20, azimuth_deg=250, depth=1.0),
    "press_e": PressConfig(CUBE, polar_deg=5, azimuth_deg=320, depth=1.2),
    "press_f": PressConfig(CYL, polar_deg=18, azimuth_deg=10, depth=1.0),
    "press_g": PressConfig(SPHERE, polar_deg=10, azimuth_deg=160, depth=1.4),
}
HELD_OUT = "press_g"


def small_twin(**camera):
    return load_scene().replace(
        noise={"enabled": True}, render={"bounces": 0, "spp": 1}, camera={"width": WIDTH, "height": HEIGHT} | camera
    )


@pytest.fixture(scope="session")
def twin_presses(tmp_path_factory):
    """Folder with reference/ and press_*/ rendered and NLiPs-solved (PRESS/nlips)."""
    from nlipscalib.core import load_press
    from nlipscalib.core.reconstruction import save_reconstruction
    from nlipscalib.solver import solve_press

    root = tmp_path_factory.mktemp("learn_twin")
    scene = small_twin()
    render_press(scene, None, root / "reference", seed=1)
    ref = load_press(root / "reference")
    for i, (name, cfg) in enumerate(PRESSES.items()):
        render_press(scene, cfg, root / name, seed=10 + i)
        press = load_press(root / name)
        save_reconstruction(
            solve_press(press, roi="auto", indirect=ref, dent_interreflection=False), root / name / "nlips"
        )
    return root


@pytest.fixture(scope="session")
def calib(twin_presses, tmp_path_factory):
    from nlipscalib.learn.dataset import CalibrationDataset, build_dataset

    out = tmp_path_factory.mktemp("learn_calib") / "calib"
    build_dataset(sorted(twin_presses.glob("press_*")), twin_presses / "reference", out, progress=False)
    return CalibrationDataset(out)


@pytest.fixture(scope="session")
def trained(calib, tmp_path_factory):
    """The paper's NLiPsNet (its linear colour inputs: ``colour_input="linear"``, no longer the default) trained on
    NLiPs labels, HELD_OUT never seen (neither train nor validation). Pinned to the paper's inputs: the tests that
    use it check the linear path and files of linear colours (as every model made before the thirty-seventh session
    is); ``trained_ratio`` is the default's."""
    from nlipscalib.learn.train import TrainConfig, train

    out = tmp_path_factory.mktemp("learn_model") / "net.pt"
    cfg = TrainConfig(max_epochs=25, patience=8, colour_input="linear")
    train(calib, cfg, out, val_names=["press_d"], exclude=[HELD_OUT], progress=False)
    return out


@pytest.fixture(scope="session")
def trained_ratio(calib, tmp_path_factory):
    """A small NLiPsNet of colour ratios (``TrainConfig.colour_input`` "ratio", the default; said explicitly so that
    the fixture stays the ratio's), HELD_OUT never seen."""
    from nlipscalib.learn.train import TrainConfig, train

    out = tmp_path_factory.mktemp("learn_model_ratio") / "ratio.pt"
    cfg = TrainConfig(hidden=(32, 32), dropout=0.0, max_epochs=4, batch_size=256, colour_input="ratio")
    train(calib, cfg, out, val_names=["press_d"], exclude=[HELD_OUT], progress=False)
    return out


@pytest.fixture(scope="session")
def trained_ratio_paper(calib, tmp_path_factory):
    """The paper's NLiPsNet of colour ratios (the default's inputs and reference Gaussian), trained as ``trained``
    is: the net whose whole-gel depth the full-frame tests bound (``trained_ratio``, 4 epochs of a 32-32 net, fits
    the flat gel too loosely for that, as a linear net of its size does)."""
    from nlipscalib.learn.train import TrainConfig, train

    out = tmp_path_factory.mktemp("learn_model_ratio_paper") / "ratio_paper.pt"
    cfg = TrainConfig(max_epochs=25, patience=8, colour_input="ratio")
    train(calib, cfg, out, val_names=["press_d"], exclude=[HELD_OUT], progress=False)
    return out
