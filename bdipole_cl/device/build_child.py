"""The guarded builds' child process (``guard``): ``python -m bdipole_cl.device.build_child
--device P:D`` opens the device, says ``{"ready": true}``, then for each request line
``{"source": ..., "options": [...]}`` builds the program, asks for its binaries (PoCL generates
machine code then) and creates every kernel, and answers ``{"built": true|false}`` (false: a
compile error, which is no crash). A crash ends it: the parent reads that as the answer.

``isolation.FAULT_VARIABLE`` (tests): ``build:TEXT=segv`` (or ``=kill``) kills it building a
program whose options contain TEXT.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

from .children import die_with, emit, inject_fault
from .isolation import FAULT_VARIABLE
from .runtime import PROBE_CHILD_VARIABLE, build_quietly, runtime_at

def _inject_fault(options):
    """The fault FAULT_VARIABLE asks for a build whose options contain its text (tests)."""
    joined = " ".join(options)
    inject_fault(os.environ.get(FAULT_VARIABLE, ""),
                 lambda target: target.startswith("build:") and target[6:] in joined)


def _build_everything(rt, source, options) -> bool:
    """Build, ask for the binaries (PoCL's code generation), create every kernel: whether it
    built. A compile error is no crash, nor is a Python error (pyopencl's cache folder
    unwritable): the parent's own build reports either, and nothing is recorded as a crash."""
    try:
        _inject_fault(options)
        prg = build_quietly(rt.context, source, options)
    except Exception:
        return False
    import pyopencl as cl
    prg.get_info(cl.program_info.BINARY_SIZES)
    prg.all_kernels()
    return True


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bdipole_cl.device.build_child")
    parser.add_argument("--device", required=True, help="P:D, as `bdipole-cl devices` lists")
    parser.add_argument("--parent", type=int, help="end when this process ends")
    args = parser.parse_args(argv)
    if args.parent:
        die_with(args.parent)
    os.environ[PROBE_CHILD_VARIABLE] = "1"            # its device opened unprobed
    try:
        rt = runtime_at(args.device)
    except Exception as exc:       # every driver failure: the device cannot be opened at all
        emit({"error": " ".join(str(exc).split())[:300]})
        return 0
    emit({"ready": True})
    for line in sys.stdin:
        request = json.loads(line)
        emit({"built": _build_everything(rt, request["source"], request["options"])})
    return 0


if __name__ == "__main__":
    sys.exit(main())

