"""The ``pydynrad`` command line: one subcommand per main job.

Errors a user can cause (bad paths, bad options, unreadable meshes) end with one clear line
on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import sys

from .errors import PydynradError

__all__ = ["main"]


def _cmd_info(args: argparse.Namespace) -> int:
    from .device import default_device, list_devices

    print("OpenCL devices (select one with PYOPENCL_CTX=<platform>:<device>):")
    for d in list_devices():
        print(f"  [{d['PYOPENCL_CTX']}] {d['platform']} / {d['device']} ({d['type']}, "
              f"{d['compute_units']} CU, {d['global_memory_MiB']} MiB)")
    print("pydynrad uses:")
    for k, v in default_device().info().items():
        print(f"  {k:18s} {v}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pydynrad",
        description="Dynamic Radiosity on OpenCL: form factors, local multibounce matrices, frame loops.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    p = sub.add_parser("info", help="list OpenCL devices and the one pydynrad uses",
                       description="List every OpenCL device and show the one pydynrad selects "
                                   "(PYOPENCL_CTX overrides the default, the first PoCL CPU device).")
    p.set_defaults(func=_cmd_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (PydynradError, OSError) as exc:
        print(f"pydynrad {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"pydynrad {args.command}: interrupted", file=sys.stderr)
        return 130
