"""NumPy's huge-page advice off while the solver runs, and back as it was afterwards."""

import numpy as np
import pytest

from nlipscalib.core import pages
from nlipscalib.solver import solve

from . import synth


def _advice() -> bool:
    setter = pages._setter()
    now = setter(True)
    setter(now)
    return now


@pytest.mark.skipif(pages._setter() is None, reason="this NumPy has no huge-page switch")
@pytest.mark.parametrize("before", [True, False])
def test_ordinary_pages_inside_and_numpys_setting_back_after(before):
    setter = pages._setter()
    original = setter(before)
    try:
        outer, inner = pages.ordinary_pages(), pages.ordinary_pages()
        outer.__enter__()
        assert _advice() is False
        inner.__enter__()  # another thread's solve: shares the setting
        outer.__exit__(None, None, None)  # the first leaves before the second: still off
        assert _advice() is False
        inner.__exit__(None, None, None)
        assert _advice() is before
    finally:
        setter(original)


@pytest.mark.skipif(pages._setter() is None, reason="this NumPy has no huge-page switch")
def test_a_solve_runs_without_huge_pages_and_restores_the_setting(monkeypatch, tmp_path):
    from nlipscalib.core import load_press
    from nlipscalib.solver import nlips  # the entry calls solve_coarse_to_fine under its own name

    seen = []
    inner = nlips.solve_coarse_to_fine

    def watched(*args, **kwargs):
        seen.append(_advice())
        return inner(*args, **kwargs)

    monkeypatch.setattr(nlips, "solve_coarse_to_fine", watched)
    press = load_press(synth.make_press(tmp_path / "p", "sphere", size=(48, 36)))
    before = _advice()
    result = solve(press.linear(press.led_images), press.camera, press.leds, prior_depth=press.reference.depth)
    assert seen == [False] and _advice() is before
    assert np.isfinite(result.depth[result.reconstructed]).all()
