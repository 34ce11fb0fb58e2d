"""NLiPsNet training speed: one step (the net's byte-mask dropout against torch.nn.Dropout), or whole epochs of
``nlips train`` on a calibration dataset per device (``--device cuda``).

Usage::

    python benchmarks/bench_train_step.py [--batch 1024] [--threads 2] [--rounds 7] [--device cpu] [--write]
    python benchmarks/bench_train_step.py --dataset CALIB [--devices cpu,cuda] [--epochs 3] [--rounds 2] [--out OUT]

Step mode times forward + cosine loss + backward + Adam step of the paper's net (256-256-128, BatchNorm, ReLU,
dropout 0.2) on random inputs on ``--device``, the two dropouts alternating round by round (same process, same
load), and prints the median milliseconds per step of each and the ratio. Steps per epoch of ``nlips train`` =
samples / batch.

Epoch mode (``--dataset``) trains the paper's net on the dataset's seeded split with :func:`learn.train.train`, as
``nlips train --device D`` does, ``--epochs`` epochs on each of ``--devices`` in turn, ``--rounds`` times
(alternating: the same load for each), and reports each device's seconds per epoch (from the training's history:
an epoch and its validation; the first epoch, with the device's warm-up, reported apart), the whole training's wall
and process CPU (moving the samples, checkpoints and the model file included) and the best validation AAE. Then it
checks what a GPU run writes: the model file and checkpoint hold CPU tensors only (loaded without map_location),
the largest weight difference between the devices' models (other rounding and other dropout masks: not zero),
and that the last device's model resumes on the first device, saying so. Results: stdout and OUT/train_device.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))


def _device(check_device, name: str):
    """``check_device(name)``, or exit with its one line (no GPU here, a CPU build of torch), before any work."""
    from nlipscalib.core.errors import NlipsError

    try:
        return check_device(name, flag=True)  # worded for this script's --device
    except NlipsError as exc:
        raise SystemExit(f"bench_train_step.py: {exc}") from None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--steps", type=int, default=100, help="steps per round and dropout")
    ap.add_argument("--write", action="store_true", help="write the table into RESULTS.md")
    ap.add_argument("--device", default="cpu", help="step mode: torch device of the steps (cpu, cuda, cuda:N)")
    ap.add_argument("--dataset", help="calibration dataset: time whole epochs of `nlips train` (epoch mode)")
    ap.add_argument("--devices", default="cpu,cuda", help="epoch mode: devices, comma-separated (default cpu,cuda)")
    ap.add_argument("--epochs", type=int, default=3, help="epoch mode: epochs per training (default 3)")
    ap.add_argument("--hidden", default="256,256,128", help="epoch mode: hidden widths (default: the paper's)")
    ap.add_argument("--out", default="train_device_out", help="epoch mode: folder of the models and the JSON")
    args = ap.parse_args()
    if args.dataset:
        epochs(args)
        return

    import torch

    from nlipscalib.learn.torch_device import check_device

    device = _device(check_device, args.device)

    from nlipscalib.learn.model import build_net, cosine_loss

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    x = (torch.rand(args.batch, 5) * torch.tensor([640.0, 480.0, 1.0, 1.0, 1.0])).to(device)
    y = torch.nn.functional.normalize(torch.randn(args.batch, 3), dim=-1).to(device)

    def net_with(dropout_type):
        net = build_net()
        if dropout_type is not None:
            for i, m in enumerate(net.mlp):
                if isinstance(m, torch.nn.Dropout):
                    net.mlp[i] = dropout_type(m.p)
        net.to(device)
        return net.train(), torch.optim.Adam(net.parameters(), lr=2e-3)

    cases = {"torch.nn.Dropout": net_with(torch.nn.Dropout), "byte-mask dropout (the net's)": net_with(None)}
    times = {name: [] for name in cases}
    for _ in range(args.rounds):
        for name, (net, opt) in cases.items():
            for k in range(10 + args.steps):
                if k == 10:
                    _synchronize(device)
                    t0 = time.perf_counter()
                opt.zero_grad()
                cosine_loss(net(x), y).backward()
                opt.step()
            _synchronize(device)  # a GPU's steps are queued: the time is theirs once they are done
            times[name].append((time.perf_counter() - t0) / args.steps * 1e3)
    base, new = (statistics.median(t) for t in times.values())
    rows = [f"| {name} | {statistics.median(t):.2f} | {min(t):.2f} - {max(t):.2f} |" for name, t in times.items()]
    body = "\n".join(
        [
            f"Paper's net on {device}, batch {args.batch}, {args.threads} threads, torch {torch.__version__}; "
            f"{args.rounds} rounds of {args.steps} steps per dropout, alternating; load average before "
            f"{os.getloadavg()[0]:.2f}.",
            "",
            "| dropout | ms per step (median) | range over rounds |",
            "|---|---|---|",
            *rows,
            "",
            f"Step time ratio byte-mask / torch.nn.Dropout: {new / base:.3f}.",
        ]
    )
    print(body)
    if args.write:
        from common import write_section

        write_section("NLiPsNet training step: byte-mask dropout (bench_train_step.py)", body)


def _synchronize(device) -> None:
    import torch

    if device.type == "cuda":
        torch.cuda.synchronize(device)


def epochs(args: argparse.Namespace) -> None:
    """Epoch mode (module docstring)."""
    import json
    import logging
    from pathlib import Path

    import torch

    from nlipscalib.learn.checkpoint import checkpoint_path
    from nlipscalib.learn.dataset import CalibrationDataset
    from nlipscalib.learn.torch_device import check_device
    from nlipscalib.learn.train import TrainConfig, train

    devices = [str(_device(check_device, d)) for d in args.devices.split(",")]
    hidden = tuple(int(h) for h in args.hidden.split(","))
    cfg = TrainConfig(hidden=hidden, max_epochs=args.epochs, patience=args.epochs, threads=args.threads)
    data, out = CalibrationDataset(args.dataset), Path(args.out)
    load = os.getloadavg()[0]
    runs = {d: [] for d in devices}
    for r in range(args.rounds):
        for d in devices:
            model = out / f"round{r}-{d.replace(':', '_')}" / "net.pt"
            wall, cpu = time.perf_counter(), time.process_time()
            res = train(data, cfg, model, progress=False, device=d)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            secs = [h["seconds"] for h in res.history]
            runs[d].append(
                {
                    "model": str(model),
                    "epoch_s": secs,
                    "wall_s": wall,
                    "cpu_s": cpu,
                    "best_val_aae_deg": res.history[res.best_epoch]["val_aae_deg"],
                }
            )
            print(f"round {r} {d}: epochs {', '.join(f'{s:.2f}' for s in secs)} s; wall {wall:.1f} s, CPU {cpu:.1f} s")

    def tensors(obj):
        if isinstance(obj, torch.Tensor):
            yield obj
        elif isinstance(obj, (dict, list, tuple)):
            for v in obj.values() if isinstance(obj, dict) else obj:
                yield from tensors(v)

    checks = {}
    for d in devices:  # what each device's run wrote loads anywhere: CPU tensors only, without map_location
        model = Path(runs[d][-1]["model"])
        kinds = {
            t.device.type for p in (model, checkpoint_path(model)) for t in tensors(torch.load(p, weights_only=True))
        }
        checks[f"{d}: devices of the tensors in the model and checkpoint"] = sorted(kinds)
    first, last = (torch.load(runs[d][-1]["model"], weights_only=True)["state_dict"] for d in (devices[0], devices[-1]))
    checks[f"max |weight {devices[0]} - {devices[-1]}|"] = max(float((first[k] - last[k]).abs().max()) for k in first)
    # the last device's run resumed on the first for one more epoch: a checkpoint of one device goes on on the other
    logged = []
    handler = logging.Handler()
    handler.emit = lambda record: logged.append(record.getMessage())
    logging.getLogger("nlipscalib").addHandler(handler)
    logging.getLogger("nlipscalib").setLevel(logging.INFO)
    more = dataclasses.replace(cfg, max_epochs=args.epochs + 1, patience=args.epochs + 1)
    resumed = train(data, more, Path(runs[devices[-1]][-1]["model"]), progress=False, device=devices[0])
    checks["resumed on the first device"] = [m for m in logged if "resuming after epoch" in m]
    checks["epoch devices of the resumed run"] = [h.get("device") for h in resumed.history]

    def row(d: str) -> str:
        later = [s for run in runs[d] for s in run["epoch_s"][1:]]
        firsts = [run["epoch_s"][0] for run in runs[d]]
        walls, cpus = [run["wall_s"] for run in runs[d]], [run["cpu_s"] for run in runs[d]]
        aae = [run["best_val_aae_deg"] for run in runs[d]]
        return (
            f"| {d} | {statistics.median(later):.2f} ({min(later):.2f} - {max(later):.2f}) | "
            f"{statistics.median(firsts):.2f} | {statistics.median(walls):.1f} | {statistics.median(cpus):.1f} | "
            f"{min(aae):.2f} - {max(aae):.2f} |"
        )

    gpu = torch.cuda.get_device_name() if torch.cuda.is_available() else "none"
    body = "\n".join(
        [
            f"{len(data.names)}-press dataset {args.dataset}, net {args.hidden}, batch {cfg.batch_size}, "
            f"{args.epochs} epochs x {args.rounds} rounds per device, alternating; torch {torch.__version__}, GPU "
            f"{gpu}, {args.threads} CPU thread(s); load average before {load:.2f}.",
            "",
            "| device | s per epoch after the first (median, range) | first epoch s | training wall s | CPU s | "
            "best val AAE deg |",
            "|---|---|---|---|---|---|",
            *(row(d) for d in devices),
            "",
            *(f"- {k}: {v}" for k, v in checks.items()),
        ]
    )
    print(body)
    (out / "train_device.json").write_text(
        json.dumps({"runs": runs, "checks": checks, "table": body}, indent=1), encoding="utf-8"
    )


if __name__ == "__main__":
    main()
