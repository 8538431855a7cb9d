"""Shared measuring helpers for the benchmarks: timing and this machine's copy bandwidth.

Bandwidths are reported in GB/s (1e9 bytes/s). A copy counts its bytes twice (read + write),
so "copy bandwidth" is directly comparable with a kernel's bytes read plus written.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["time_call", "copy_bandwidth_numpy", "copy_bandwidth_device", "run_standalone"]


def time_call(fn, repeats: int = 5, warmup: int = 1) -> dict:
    """Time ``fn()``: ``warmup`` untimed-for-the-median calls (their time is reported as
    ``warmup_s``: kernel builds, first-touch page faults), then ``repeats`` timed calls.

    Returns {"median_s", "min_s", "warmup_s", "repeats", "result"} (``result``: the last return value).
    """
    t0 = time.perf_counter()
    result = None
    for _ in range(warmup):
        result = fn()
    warm = time.perf_counter() - t0
    times = []
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t)
    return {
        "median_s": float(np.median(times)),
        "min_s": float(min(times)),
        "warmup_s": warm,
        "repeats": len(times),
        "result": result,
    }


def copy_bandwidth_numpy(nbytes: int = 256 * 2**20, repeats: int = 5) -> float:
    """GB/s of ``np.copyto`` between two large float32 arrays (read + write counted)."""
    src = np.ones(nbytes // 4, dtype=np.float32)
    dst = np.zeros_like(src)  # both touched before timing: no page faults inside
    t = time_call(lambda: np.copyto(dst, src), repeats=repeats)
    return 2 * src.nbytes / t["median_s"] / 1e9


def copy_bandwidth_device(device, nbytes: int = 256 * 2**20, repeats: int = 5) -> float:
    """GB/s of an OpenCL buffer-to-buffer copy on ``device`` (read + write counted)."""
    import pyopencl as cl

    nbytes = min(nbytes, device.max_alloc_bytes // 2)
    mf = cl.mem_flags
    src = cl.Buffer(device.context, mf.READ_WRITE, nbytes)
    dst = cl.Buffer(device.context, mf.READ_WRITE, nbytes)
    cl.enqueue_fill_buffer(device.queue, src, np.float32(1), 0, nbytes)
    cl.enqueue_fill_buffer(device.queue, dst, np.float32(0), 0, nbytes)
    device.queue.finish()

    def copy():
        cl.enqueue_copy(device.queue, dst, src)
        device.queue.finish()

    t = time_call(copy, repeats=repeats)
    return 2 * nbytes / t["median_s"] / 1e9


def run_standalone(name: str, doc: str, sizes, measure, argv=None) -> int:
    """``python -m bench.<name> [--size S] [--out DIR]``: run ``measure(size, device)`` (one
    report section) and write ``<out>/<name>.json`` and ``.md`` (default out:
    bench/results/<device-slug>, and the index of bench/results is rewritten)."""
    import argparse
    import sys

    import pydynrad

    from .report import device_dir, write_index, write_report

    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--size", choices=list(sizes), default="quick")
    ap.add_argument("--out", default=None, help="report folder (default: bench/results/<device-slug>)")
    args = ap.parse_args(argv)
    device = pydynrad.default_device()
    t0 = time.perf_counter()
    section = measure(args.size, device)
    results = {
        "device": device.info(),
        "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "size": args.size,
        "sections": {name: section},
        "seconds": time.perf_counter() - t0,
    }
    written = write_report(results, args.out or device_dir(results["device"]), name)
    if args.out is None:
        write_index()
    print("\n".join(str(p) for p in written.values()), file=sys.stderr)
    return 0


def entry_points(name: str, doc: str, sizes, measure):
    """The two entry points of a bench module whose ``measure(size, device, progress=)`` takes
    no suite parameters: the suite's section (at the suite's size, "quick" where the module has
    no such size) and ``python -m bench.<name>`` (:func:`run_standalone`)."""

    def suite_section(ctx) -> dict:
        return measure(ctx.size if ctx.size in sizes else "quick", ctx.device, progress=ctx.progress)

    def main(argv=None) -> int:
        return run_standalone(name, doc, sizes, measure, argv)

    suite_section.__doc__ = f"The suite's \"{name}\" section at the suite's size."
    return suite_section, main
