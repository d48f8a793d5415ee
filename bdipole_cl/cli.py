"""``bdipole-cl``: command-line entry point (a thin layer over the Python API)."""
from __future__ import annotations

import argparse
import sys

EPILOG = """examples:
  bdipole-cl devices
  bdipole-cl demo                      # built-in example: textures in, coefficients out
"""


def _cmd_devices(args) -> int:
    from .device import device_has_fp64, get_runtime, list_devices
    pairs = list_devices()
    if not pairs:
        print("no OpenCL devices found", file=sys.stderr)
        return 1
    chosen = get_runtime().device
    for i, (platform, d) in enumerate(pairs):
        mark = "*" if d.int_ptr == chosen.int_ptr else " "
        print(f"{mark} [{i}] {d.name.strip()} | {platform.name.strip()} | {d.version.strip()} | "
              f"{d.max_compute_units} CUs | {d.global_mem_size / 2**30:.1f} GiB | "
              f"fp64: {'yes' if device_has_fp64(d) else 'no'}")
    print("* = the device bdipole-cl uses (PYOPENCL_CTX overrides)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bdipole-cl", description=__doc__.split("\n")[0],
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("devices", help="list OpenCL devices and the one in use")
    p.set_defaults(func=_cmd_devices)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
