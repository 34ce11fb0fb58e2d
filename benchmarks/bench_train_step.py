"""One NLiPsNet training step on the CPU: the net's byte-mask dropout against torch.nn.Dropout.

Usage::

    python benchmarks/bench_train_step.py [--batch 1024] [--threads 2] [--rounds 7] [--write]

Times forward + cosine loss + backward + Adam step of the paper's net (256-256-128, BatchNorm, ReLU, dropout
0.2) on random inputs, the two dropouts alternating round by round (same process, same load), and prints the
median milliseconds per step of each and the ratio. Steps per epoch of ``nlips train`` = samples / batch.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--steps", type=int, default=100, help="steps per round and dropout")
    ap.add_argument("--write", action="store_true", help="write the table into RESULTS.md")
    args = ap.parse_args()

    import torch

    from nlipscalib.learn.model import build_net, cosine_loss

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    x = torch.rand(args.batch, 5) * torch.tensor([640.0, 480.0, 1.0, 1.0, 1.0])
    y = torch.nn.functional.normalize(torch.randn(args.batch, 3), dim=-1)

    def net_with(dropout_type):
        net = build_net()
        if dropout_type is not None:
            for i, m in enumerate(net.mlp):
                if isinstance(m, torch.nn.Dropout):
                    net.mlp[i] = dropout_type(m.p)
        return net.train(), torch.optim.Adam(net.parameters(), lr=2e-3)

    cases = {"torch.nn.Dropout": net_with(torch.nn.Dropout), "byte-mask dropout (the net's)": net_with(None)}
    times = {name: [] for name in cases}
    for _ in range(args.rounds):
        for name, (net, opt) in cases.items():
            for k in range(10 + args.steps):
                if k == 10:
                    t0 = time.perf_counter()
                opt.zero_grad()
                cosine_loss(net(x), y).backward()
                opt.step()
            times[name].append((time.perf_counter() - t0) / args.steps * 1e3)
    base, new = (statistics.median(t) for t in times.values())
    rows = [f"| {name} | {statistics.median(t):.2f} | {min(t):.2f} - {max(t):.2f} |" for name, t in times.items()]
    body = "\n".join(
        [
            f"Paper's net, batch {args.batch}, {args.threads} threads, torch {torch.__version__}; {args.rounds} rounds "
            f"of {args.steps} steps per dropout, alternating; load average before {os.getloadavg()[0]:.2f}.",
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


if __name__ == "__main__":
    main()
