"""What a kept `nlips train` re-run spends recognising its samples (s42-trainid), in process, this checkout:

- the records (``CalibrationDataset.samples_key``: index.json's digests of the sample files, then
  ``samples_changed``: each file's size and SHA-256), what the re-run now reads;
- the samples themselves (``learn.train._training_data``: every shard read, inflated and checked, made into the
  network's inputs, then ``checkpoint.data_key_of``), what it read before and still reads for a dataset without the
  records.

CPU ms (``time.process_time``) median [range] over ``--repeats`` calls after one warm-up (the files in the page
cache, as on a re-run). The whole-process A/B of the re-run is ``bench_reused_train.py --reruns-only``.

Run: .venv/bin/python benchmarks/bench_samples_key.py /tmp/s42/trainid-ds/calibration [--repeats 5]
Prints Markdown; the results are in benchmarks/RESULTS.md (s42-trainid).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def cpu_ms(fn, repeats: int) -> list[float]:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append((time.process_time() - t0) * 1e3)
    return times


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset", type=Path, help="a calibration dataset built by this checkout (its records)")
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()

    from nlipscalib.learn.checkpoint import data_key_of
    from nlipscalib.learn.dataset import SHARD_DIR, CalibrationDataset
    from nlipscalib.learn.train import TrainConfig, _presses, _training_data

    data = CalibrationDataset(args.dataset)
    cfg = TrainConfig()
    train, val = _presses(data, cfg, None, ())
    size = sum(f.stat().st_size for f in (args.dataset / SHARD_DIR).glob("*.npz"))
    if data.samples_key(train, val) is None:
        sys.exit(f"{args.dataset}: its index.json records no sample files (built before s42-trainid)")

    def records() -> None:
        assert data.samples_key(train, val) is not None and data.samples_changed([*train, *val]) is None

    def samples() -> None:
        data_key_of(*_training_data(data, cfg, None, ()).arrays())

    print(f"load average at the start: {os.getloadavg()}")
    print(f"\n{args.dataset}: {len(data.names)} presses, {size / 1e6:.1f} MB of sample files; CPU ms a call\n")
    print("| what the re-run reads | CPU ms median [range] |\n|---|---|")
    for name, fn in (("the records (key, then sizes and SHA-256 of the files)", records), ("the samples", samples)):
        times = cpu_ms(fn, args.repeats)
        print(f"| {name} | {statistics.median(times):.0f} [{min(times):.0f}-{max(times):.0f}] |")
    print(f"\nload average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
