"""``bdipole-cl devices``: every OpenCL device with its state (its probe's verdict: works,
the configurations it rejected, or broken and why), the environment runtimes, and the device in
use (docs/runtimes.md)."""
from __future__ import annotations

import sys


def add_command(command):
    p = command("devices", help="list OpenCL devices, their probes' verdicts and the one in use")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..device import REMEDIES, DeviceError, get_runtime, survey
    from ..device.icd import register_environment_runtimes
    states = survey()
    try:
        chosen = get_runtime(args.device).device.int_ptr
    except DeviceError as exc:
        chosen = None
        problem = str(exc)
    for s in states:
        mark = "*" if s.device.int_ptr == chosen else " "
        print(f"{mark} {s.describe()}")
    for r in register_environment_runtimes():
        how = "registered" if r.registered else "not registered"
        print(f"  environment runtime: {r.name} at {r.library} ({how}"
              + (f"; {r.note}" if r.note else "") + ")")
    if chosen is None:
        print(f"bdipole-cl devices: error: {problem}", file=sys.stderr)
        return 1
    print("* = the device bdipole-cl uses (--device or PYOPENCL_CTX choose another)")
    if not any(s.works for s in states):
        print(REMEDIES)
    return 0
