"""docs/experiments/: the pages that list the committed reports name every one of them, and describe their size.

s28-docs2 found `q2-steep-refined/` (committed 2026-12-05) missing from the README's "Reports in this folder" and
`q2/` named at the commit of the run it replaced: a reader looking for a report's origin was sent astray."""

from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "docs" / "experiments"
FULL_TWIN = {"width": 640, "height": 480, "spp": 16}
"""The full size's render settings, which the README says every committed report has."""


def _reports() -> dict[str, dict]:
    return {
        p.parent.name: json.loads(p.read_text(encoding="utf-8")) for p in sorted(EXPERIMENTS.glob("*/results.json"))
    }


def _reports_paragraph() -> str:
    text = (EXPERIMENTS / "README.md").read_text(encoding="utf-8")
    return text.split("## Reports in this folder", 1)[1]


def test_every_committed_report_is_named_with_its_commit():
    reports = _reports()
    assert len(reports) >= 9  # the folders were found
    paragraph = _reports_paragraph()
    results_table = (EXPERIMENTS / "RESULTS.md").read_text(encoding="utf-8").split("\n## ", 1)[0]
    unnamed = {name for name in reports if f"`{name}/`" not in paragraph or f"`{name}/`" not in results_table}
    assert unnamed == set()
    # the commit a report's results.json records is its last run's; a run that only rebuilt the report from
    # finished tasks may differ from the one the pages name, so each page must name one of the two
    wrong = {}
    for name, results in reports.items():
        commit = results["software"]["git_commit"][:7]
        # "`q1/` at `b43542d`", or "`q2-steep/` at `86233d4` (2026-12-03)" across a line break
        named = re.search(rf"`{re.escape(name)}/`\s+at\s+`([0-9a-f]{{7}})`", paragraph)
        if named is None or (named[1] != commit and commit not in paragraph):
            wrong[name] = (named and named[1], commit)
    assert wrong == {}


def test_every_committed_report_is_at_the_full_size_render_settings():
    """The README: "Every report here is a full-size run (640x480 px, 16 spp)", variants "size custom"."""
    sizes = {name: (r["size"], {k: r["config"]["twin"][k] for k in FULL_TWIN}) for name, r in _reports().items()}
    assert {name: s for name, s in sizes.items() if s[0] not in ("full", "custom") or s[1] != FULL_TWIN} == {}
    custom = sorted(name for name, s in sizes.items() if s[0] == "custom")
    assert custom == sorted(set(re.findall(r"`(q2-[\w-]+)/`", _reports_paragraph())))


CONFIG_EXAMPLES = {"my_ablation.toml": "ablation", "q2_more.toml": "q2"}
"""The ```toml config files docs/experiments/README.md shows, by the name its first comment gives, and the experiment
whose ``--config`` the page gives each to."""


def test_every_config_file_the_page_shows_loads_into_its_experiment_with_the_values_it_sets(tmp_path):
    """s32-docwalk: the page's `--config` examples were read by no test; a renamed field or section would reach a lab
    as "unknown key(s)" on the first copy, and a key read into another field would pass the load silently."""
    import tomllib

    from nlipscalib.experiments import get

    blocks = re.findall(r"```toml\n(.*?)```", (EXPERIMENTS / "README.md").read_text(encoding="utf-8"), re.S)
    files = {block.splitlines()[0].removeprefix("#").strip(): block for block in blocks}
    assert set(files) == set(CONFIG_EXAMPLES)  # a new example is mapped here to its experiment
    for name, block in files.items():
        path = tmp_path / name
        path.write_text(block, encoding="utf-8")
        cfg = get(CONFIG_EXAMPLES[name]).config(config_file=path)  # as `nlips experiment NAME --config FILE`
        for key, value in tomllib.loads(block).items():
            section = getattr(cfg, key)
            for field, set_to in value.items() if isinstance(value, dict) else [(None, value)]:
                got = section if field is None else getattr(section, field)
                if isinstance(set_to, list) and set_to and isinstance(set_to[0], dict):  # indenters: their kinds
                    got, set_to = [i.kind for i in got], [i["kind"] for i in set_to]
                assert (list(got) if isinstance(got, tuple) else got) == set_to, (name, key, field)


def test_the_sizes_the_page_gives_are_the_experiments_configs():
    """s32-docwalk: the page's "Sizes" paragraph (96x72 px at 8 spp, the reference at 64; 320x240 and 640x480 at 16;
    74 + 200 + 145 + 143 full-size tasks, Q2's 75) and Q2's press counts were checked against nothing."""
    from nlipscalib.experiments import get

    text = " ".join((EXPERIMENTS / "README.md").read_text(encoding="utf-8").split())
    full = re.search(r"q1, ablation, q3, studies (\d+) \+ (\d+) \+ (\d+) \+ (\d+) tasks; q2 (\d+) tasks", text)
    counts = dict(zip(("q1", "ablation", "q3", "studies", "q2"), map(int, full.groups())))
    assert {name: len(get(name).tasks(get(name).config("full"))) for name in counts} == counts
    twins = {size: get("q1").config(size).twin for size in ("quick", "medium", "full")}
    assert "`quick` (CI: 96x72 px, 8 spp with the undeformed reference at 64 spp" in text
    assert (twins["quick"].width, twins["quick"].height, twins["quick"].spp, twins["quick"].reference_spp) == (
        96,
        72,
        8,
        64,
    )
    assert "`medium` (320x240 px, 16 spp" in text and "`full` (640x480 px, 16 spp" in text
    assert [(t.width, t.height, t.spp) for t in (twins["medium"], twins["full"])] == [(320, 240, 16), (640, 480, 16)]
    said = re.search(
        r"quick: (\d+) calibration \+ (\d+) seen \+ (\d+) unseen presses at 96x72 px; medium: (\d+) \+ "
        r"(\d+) \+ (\d+) at 320x240; full: (\d+) \+ (\d+) \+ (\d+) at 640x480",
        text,
    )
    presses = [int(n) for n in said.groups()]
    for i, size in enumerate(("quick", "medium", "full")):  # one reference task beside the presses
        assert len(get("q2").tasks(get("q2").config(size))) == 1 + sum(presses[3 * i : 3 * i + 3]), size
