"""``nlips dataset SPEC --out DIR``: render many presses in parallel, resumably."""

from __future__ import annotations

import sys


def register(sub) -> None:
    p = sub.add_parser(
        "dataset",
        help="render many presses from a dataset spec (grid or random), in parallel, resumable",
        description="Render every press of a dataset spec (TOML/YAML, see scenes/datasets/). "
        "Presses already rendered are skipped, so an interrupted run resumes where it stopped.",
    )
    p.add_argument("spec", help="dataset spec file, e.g. scenes/datasets/train50.toml")
    p.add_argument("--out", required=True, help="folder that receives one press folder per press")
    p.add_argument("--workers", type=int, default=0, help="render processes (default: one per two cores)")
    p.add_argument("--limit", type=int, default=0, help="render only the first N presses of the spec")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from ..sim.dataset import expand_jobs, load_dataset_spec, run_dataset, write_manifest

    spec, scene = load_dataset_spec(args.spec)
    jobs = expand_jobs(spec)
    if args.limit:
        jobs = jobs[: args.limit]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_manifest(out, spec, scene, jobs)
    result = run_dataset(scene, jobs, out, workers=args.workers, progress=not args.no_progress)
    print(
        f"{out}: {len(result['rendered'])} rendered, {len(result['skipped'])} already there, "
        f"{len(result['failed'])} failed"
    )
    for name, error in result["failed"]:
        print(f"  {name}: {error}", file=sys.stderr)
    return 1 if result["failed"] else 0
