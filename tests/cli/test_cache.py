"""``nlips cache`` when a file stands where the cache folder should be."""

from nlipscalib.cli import main
from nlipscalib.core import diskcache


def test_clear_with_a_file_as_the_cache_folder_is_an_error_naming_the_variable(tmp_path, monkeypatch, capsys):
    """``NLIPS_CACHE_DIR=FILE nlips cache --clear`` warned and exited 0, as if it had cleared something."""
    afile = tmp_path / "afile"
    afile.write_text("not a folder", encoding="utf-8")
    monkeypatch.setattr(diskcache, "_warned", set())
    monkeypatch.setenv(diskcache.ENV_DIR, str(afile))
    assert main(["cache", "--clear"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"nlips cache: error: NLIPS_CACHE_DIR={afile}: a file, not a folder; nothing to clear (set NLIPS_CACHE_DIR "
        "to a folder, or to 'off')"
    ]
    assert afile.read_text(encoding="utf-8") == "not a folder"
    # the default folder (no NLIPS_CACHE_DIR) is named as such
    monkeypatch.delenv(diskcache.ENV_DIR)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    (tmp_path / "nlipscalib").write_text("not a folder", encoding="utf-8")
    assert main(["cache", "--clear"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{tmp_path / 'nlipscalib'} (the default cache folder): a file, not a folder" in err[0]


def test_showing_a_cache_that_a_file_turns_off_is_no_error(tmp_path, monkeypatch, capsys):
    """Only --clear fails: ``nlips cache`` reports the cache off (solves warn once and go on without it)."""
    monkeypatch.setattr(diskcache, "_warned", set())
    (tmp_path / "afile").write_text("not a folder", encoding="utf-8")
    monkeypatch.setenv(diskcache.ENV_DIR, str(tmp_path / "afile"))
    assert main(["cache"]) == 0
    assert capsys.readouterr().out.startswith("cache: off")
