"""The torch integrators' per-frame time for the regions the CPU solves in a rim box or on its sparse path (issue 8).

::

    PYTHONPATH=CHECKOUT python benchmarks/bench_rim_box_torch.py [--repeat 5] [--cases pad,dome] [--threads N]

Times ``FullFrame._box_points`` (the changed pixels' integration of ``nlips infer --device``, after the network) on
torch's CPU device, and the CPU path's ``integrate_on_dome`` on the same normals, per case: random smooth normals
near the flat pad's rim (a rim box on the CPU), exact normals of spheres pressed at its rim, and on the default
dome a cross over the whole image and a gel island touching no fixed pixel (the CPU's sparse path). Prints one line
per case: the median and range of ``--repeat`` calls after a warm-up call, wall and process CPU (user + sys of all
threads), ms, and the largest depth difference from the CPU's, mm. On a checkout before the rim boxes came to the
torch path (s26) it times the whole gel there (``DomeIntegrator``, set up once per sensor, not timed).
"""

from __future__ import annotations

import argparse
import functools
import time
from types import SimpleNamespace

import numpy as np


def _test_helper(module: str, name: str):
    """A helper of this checkout's tests/learn/MODULE.py, whatever checkout PYTHONPATH measures."""
    import importlib.util
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root))  # the test modules import each other as tests.learn.*
    path = root / "tests" / "learn" / f"{module}.py"
    spec = importlib.util.spec_from_file_location(f"bench_{module}", path)
    loaded = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(loaded)
    return getattr(loaded, name)


def _cases(which: set[str]):
    """(name, geo, changed, normals) per case."""
    from scipy import ndimage

    from nlipscalib.learn.integrate_geometry import RayGeometry

    if "pad" in which:
        rim_blob = _test_helper("test_fullframe", "_rim_blob")
        flat_pad = _test_helper("test_integrate", "_flat_pad")
        pressed = _test_helper("test_integrate", "_sphere_pressed_into_the_dome")
        for seed in range(4):
            _, geo, changed, normals = rim_blob(seed)
            yield f"pad rim, random {seed}", geo, changed, normals
        design, ref, geo, on_gel = flat_pad()
        for polar, azimuth, radius in ((48, 0, 5.0), (45, 20, 4.0)):
            _, _, hit, _, normals = pressed(design, polar, azimuth, radius, 1.0)
            changed = ndimage.binary_dilation(hit, iterations=3) & on_gel
            yield f"pad rim, sphere {polar}/{azimuth}", geo, changed, np.where(changed[..., None], normals, ref.normals)
    if "dome" in which:
        dome_and_sphere = _test_helper("test_integrate", "_dome_and_sphere")
        band = _test_helper("test_integrate", "_band")
        ref, geo, on_gel, _, _ = dome_and_sphere()
        tilt = ndimage.gaussian_filter(np.random.default_rng(5).normal(size=on_gel.shape + (3,)), (8, 8, 0)) * 20
        cross = band(on_gel.shape, 0, 200, 210) | band(on_gel.shape, 1, 300, 310)
        normals = ref.normals + np.where(cross[..., None], tilt, 0)
        yield "dome, cross both axes", geo, cross, normals / np.linalg.norm(normals, axis=-1, keepdims=True)
        depth = ref.depth.astype(np.float64)
        depth[150:250, 250:350] = np.nan
        depth[170:230, 270:330] = ref.depth[170:230, 270:330]
        island = np.zeros_like(on_gel)
        island[170:230, 270:330] = True
        normals = ref.normals + np.where(island[..., None], tilt, 0)
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
        yield "dome, gel island", RayGeometry.from_reference(geo.rays, depth), island, normals


def _timed(call, repeat: int) -> tuple[np.ndarray, np.ndarray, object]:
    """Wall and process CPU ms of ``repeat`` calls after a warm-up one, and the last result."""
    seconds, cpu_seconds = [], []
    for _ in range(repeat + 1):
        t0, c0 = time.perf_counter(), time.process_time()
        out = call()
        seconds.append(time.perf_counter() - t0)
        cpu_seconds.append(time.process_time() - c0)
    return 1e3 * np.array(seconds[1:]), 1e3 * np.array(cpu_seconds[1:]), out


def main() -> None:
    import torch

    from nlipscalib.learn import integrate_torch
    from nlipscalib.learn.fullframe import FullFrame
    from nlipscalib.learn.integrate import integrate_on_dome

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="timed calls per case")
    parser.add_argument("--cases", default="pad,dome", help="comma-separated: pad (rim boxes), dome (sparse path)")
    parser.add_argument("--threads", type=int, default=0, help="torch's CPU threads (0: its default)")
    args = parser.parse_args()
    if args.threads:  # torch's spinning worker threads cost several times the work on a loaded 2-core machine
        torch.set_num_threads(args.threads)
    cpu = torch.device("cpu")
    domes: dict[int, object] = {}
    for name, geo, changed, normals in _cases(set(args.cases.split(","))):
        box = integrate_torch.BoxIntegrator(geo, cpu)
        path = SimpleNamespace(box_integrator=box, torch=torch, device=cpu, ref_points_host=geo.points)
        if not hasattr(box, "plan"):  # before s26: the whole gel, set up once per sensor
            path.integrator = domes.setdefault(id(geo), integrate_torch.DomeIntegrator(geo, cpu))
        tensor = torch.from_numpy(np.nan_to_num(normals).astype(np.float32))
        with torch.no_grad():
            ms, cpu_ms, points = _timed(functools.partial(FullFrame._box_points, path, tensor, changed), args.repeat)
        on_cpu = functools.partial(integrate_on_dome, normals, changed, geo)
        host_ms, host_cpu_ms, (want, _) = _timed(on_cpu, args.repeat)
        diff = np.nanmax(np.abs(points[..., 2] - want))
        print(
            f"{name:24s} torch wall {np.median(ms):7.1f} ms ({ms.min():.1f}-{ms.max():.1f}),"
            f" CPU {np.median(cpu_ms):7.1f}"
            f" | integrate_on_dome wall {np.median(host_ms):7.1f} ms ({host_ms.min():.1f}-{host_ms.max():.1f}),"
            f" CPU {np.median(host_cpu_ms):7.1f} | max |torch - CPU| {diff:.1e} mm",
            flush=True,
        )


if __name__ == "__main__":
    main()
