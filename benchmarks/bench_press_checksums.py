"""What a press folder's checksums.json costs (core.press_checksums): to write, to check on a rerun, and with
``--verify``; and the whole ``nlips dataset`` rerun of a finished folder, against another checkout.

In process, on each press folder given (e.g. the 640x480 bench renders):

- the candidate hashes over the folder's files in memory (zlib's CRC-32, SHA-1, SHA-256, BLAKE2b-128): the choice;
- ``write_checksums`` (what each render or capture adds; its files are in the page cache, just written);
- the rerun's check of the folder's listed files: the ends only (``unusable_files``, before this), the ends and the
  sizes (``press_file_problems``, every rerun now) and every byte (``verify=True``).

With ``--spec SPEC --out DIR [--before-out DIR --against CHECKOUT]``: the process wall and user+sys CPU of
``nlips dataset SPEC --out DIR --no-progress`` on a finished folder (nothing to render), alternating with the other
checkout on its own folder (each side's folder rendered by its own code, so neither warns of the other's renders),
and ``--verify`` too. Every process runs from a temporary folder with its own ``PYTHONPATH``, bytecode cache and
``NLIPS_CACHE_DIR``.

Run: .venv/bin/python benchmarks/bench_press_checksums.py PRESS... [--repeats 7]
     [--spec S --out D [--before-out D2 --against CHECKOUT] [--pairs 7]]
Prints a Markdown table; the results are in benchmarks/RESULTS.md (s33-datacheck).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import interleaved, ms_spread, nlips_process, timing_rows  # noqa: E402

from nlipscalib.core.file_checks import unusable_files  # noqa: E402
from nlipscalib.core.press_checksums import CHECKSUMS_FILE, press_file_problems, write_checksums  # noqa: E402
from nlipscalib.core.press_meta import META_FILE, listed_files  # noqa: E402

HASHES = {
    "crc32 (zlib)": lambda data: zlib.crc32(data),
    "sha1": lambda data: hashlib.sha1(data).digest(),
    "sha256": lambda data: hashlib.sha256(data).digest(),
    "blake2b-128": lambda data: hashlib.blake2b(data, digest_size=16).digest(),
}


def in_process(folders: list[Path], repeats: int, scratch: Path) -> None:
    print("| press | MB | what | ms a press |\n|---|---|---|---|")
    for folder in folders:
        _one_folder(folder, repeats, scratch / folder.name)


def _one_folder(folder: Path, repeats: int, copy: Path) -> None:
    """The table's rows for ``folder``, checked on ``copy`` (its listed files and meta.json, with a record)."""
    names = listed_files(json.loads((folder / META_FILE).read_bytes()))
    datas = [(folder / n).read_bytes() for n in names]
    size = sum(map(len, datas)) / 1e6
    rows = {f"{label} (in memory)": lambda f=fn: [f(d) for d in datas] for label, fn in HASHES.items()}
    copy.mkdir()
    for name in [*names, META_FILE]:
        (copy / name).write_bytes((folder / name).read_bytes())
    # a new record each time, as into a press's new folder: replacing a file costs a flush on ext4 (auto_da_alloc)
    rows["write_checksums (read back + CRC-32)"] = lambda: _write_anew(copy, names)
    rows["rerun before: ends (unusable_files)"] = lambda: unusable_files(copy, names)
    rows["rerun now: ends + sizes"] = lambda: press_file_problems(copy, names)
    rows["--verify: ends + sizes + CRC-32"] = lambda: press_file_problems(copy, names, verify=True)
    for label, fn in rows.items():
        print(f"| {folder.name} | {size:.1f} | {label} | {ms_spread(fn, repeats, 2)} |")


def _write_anew(folder: Path, names: list[str]) -> None:
    (folder / CHECKSUMS_FILE).unlink(missing_ok=True)
    write_checksums(folder, names)


def reruns(args: argparse.Namespace) -> None:
    sides = {"now": (ROOT, args.out, [])}
    if args.against:
        sides["before"] = (Path(args.against), args.before_out, [])
    sides["now --verify"] = (ROOT, args.out, ["--verify"])

    def run(label: str) -> tuple[float, float, int]:
        checkout, out, extra = sides[label]
        argv = ["dataset", args.spec, "--out", out, "--no-progress", *extra]
        return nlips_process(checkout, argv, f"checksums-{label.split()[0]}")

    times = interleaved(list(sides), run, args.pairs, "nlips dataset")
    print(f"\n| rerun of a finished folder (n={args.pairs}, interleaved) | wall s | user+sys s |\n|---|---|---|")
    print(timing_rows(times, 2))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("presses", nargs="*", type=Path, help="press folders (read only: copied into a scratch folder)")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--spec", help="dataset spec of the finished folder --out")
    parser.add_argument("--out", help="a finished dataset folder this checkout rendered")
    parser.add_argument("--before-out", help="the same dataset rendered by the --against checkout")
    parser.add_argument("--against", help="another checkout (git worktree add --detach DIR REV)")
    parser.add_argument("--pairs", type=int, default=7)
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()}")
    if args.presses:
        with tempfile.TemporaryDirectory(prefix="bench-checksums-") as scratch:
            in_process(args.presses, args.repeats, Path(scratch))
    if args.spec:
        reruns(args)
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
