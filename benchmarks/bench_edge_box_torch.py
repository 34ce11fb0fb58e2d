"""The torch integrators' per-frame time at 640x480 for contacts at the image border (issue 8), on torch's CPU.

::

    PYTHONPATH=CHECKOUT python benchmarks/bench_edge_box_torch.py [--repeat 7]

Times ``FullFrame._box_points`` (the changed pixels' integration of ``nlips infer --device``, after the network)
on the exact normals of spheres pressed into the default dome, per case: its FFT transforms (a CPU device's) and
its dense matrix-product transforms (a GPU's branch, run here on the CPU); prints one line per case and branch:
the median and range of ``--repeat`` calls after a warm-up call, wall and process CPU (user + sys of
all threads: steadier on a loaded machine), ms. Runs on a checkout before or after the edge
boxes came to the torch path (s25): the dense branch is forced through ``BoxIntegrator._solver``.
"""

from __future__ import annotations

import argparse
import time
from types import SimpleNamespace

import numpy as np

CASES = {  # (polar deg, azimuth deg, radius mm, depth mm) of each sphere
    "middle": [(0, 0, 7.0, 2.0)],
    "border": [(50, 180, 7.0, 2.0)],
    "corner": [(55, 35, 7.0, 2.0)],
    "middle+border": [(0, 0, 5.0, 1.5), (50, 0, 7.0, 2.0)],
    "opposite borders": [(50, 180, 7.0, 2.0), (50, 0, 7.0, 2.0)],
}


def _test_helper(name: str):
    """A helper of this checkout's tests/learn/test_fullframe.py, whatever checkout PYTHONPATH measures."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "tests" / "learn" / "test_fullframe.py"
    spec = importlib.util.spec_from_file_location("bench_test_fullframe", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return getattr(module, name)


def main() -> None:
    import torch

    from nlipscalib.learn import integrate_torch
    from nlipscalib.learn.fullframe import FullFrame

    _pressed = _test_helper("_pressed")

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="timed calls per case and branch")
    args = parser.parse_args()
    cpu = torch.device("cpu")
    dome = None
    for name, spheres in CASES.items():
        _, geo, changed, _, normals = _pressed(spheres)
        dome = dome or integrate_torch.DomeIntegrator(geo, cpu)  # one sensor: set up once
        tensor = torch.from_numpy(normals.astype(np.float32))
        for dense in (False, True):
            box = integrate_torch.BoxIntegrator(geo, cpu)
            if dense:  # the GPU's branch on the CPU
                box._solver = lambda m, n: integrate_torch.BoxPoisson(m, n, cpu, torch.float32, dense=True)
            path = SimpleNamespace(
                box_integrator=box, integrator=dome, torch=torch, device=cpu, ref_points_host=geo.points
            )
            seconds, cpu_seconds = [], []
            with torch.no_grad():
                for _ in range(args.repeat + 1):  # the first: transform matrices and FFT plans made
                    t0, c0 = time.perf_counter(), time.process_time()
                    FullFrame._box_points(path, tensor, changed)
                    seconds.append(time.perf_counter() - t0)
                    cpu_seconds.append(time.process_time() - c0)
            ms, cpu_ms = 1e3 * np.array(seconds[1:]), 1e3 * np.array(cpu_seconds[1:])
            branch = "matrices" if dense else "fft"
            print(
                f"{name:17s} {branch:8s} wall median {np.median(ms):7.1f} ms (range {ms.min():.1f}-{ms.max():.1f}),"
                f" CPU median {np.median(cpu_ms):7.1f} ms (range {cpu_ms.min():.1f}-{cpu_ms.max():.1f})",
                flush=True,
            )


if __name__ == "__main__":
    main()
