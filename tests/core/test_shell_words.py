"""Paths in the commands a message suggests: copied into a shell, they are one argument each."""

import shlex

import pytest

from nlipscalib.core.shell_words import shell_word


@pytest.mark.parametrize("path", ["out/leds.json", "/tmp/x/press_0001", "C:/data/m.pt", "a-b_c.d@e%f+g=h,i"])
def test_a_path_of_safe_characters_is_printed_as_it_is(path):
    assert shell_word(path) == path


@pytest.mark.parametrize("path", ["mes données/lé ds.json", "session 1", "it's", "a;b", "$HOME/x", "~/m.pt", ""])
def test_a_path_the_shell_would_split_or_read_comes_back_whole(path):
    """`next: nlips train mes données/calibration --out MODEL.pt` pasted into bash was two arguments."""
    assert shlex.split(f"nlips train {shell_word(path)} --out m.pt") == ["nlips", "train", path, "--out", "m.pt"]
