import pytest

from nlipscalib.core import load_press

from . import synth


@pytest.fixture(scope="session")
def presses(tmp_path_factory):
    """Exact-data presses: undeformed, sphere dent, flat-faced (cube) dent."""
    root = tmp_path_factory.mktemp("solver_presses")
    return {kind: synth.make_press(root / kind, kind) for kind in ("none", "sphere", "cube")}


@pytest.fixture(scope="session")
def sphere_press(presses):
    return load_press(presses["sphere"])
