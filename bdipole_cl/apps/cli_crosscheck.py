"""``bdipole-cl crosscheck`` (applications): the built-in kernels against the float64
reference on one device or every device, or a user's kernel against a built-in function."""
from __future__ import annotations

import sys

from ..device.numerics import NUMERICS


def cmd_crosscheck(args) -> int:
    """``bdipole-cl crosscheck``: the rows printed; exit 1 on a FAIL, 2 on a usage error."""
    from .crosscheck import format_rows, run_all_devices, run_crosscheck
    from .user_kernel import UserKernelError, UserKernelRunError, check_user_kernel
    if args.user_kernel:
        if not (args.function and args.against):
            print("bdipole-cl crosscheck: error: --user-kernel needs --function and --against",
                  file=sys.stderr)
            return 2
        if args.numerics != NUMERICS.names[0]:
            print(f"bdipole-cl crosscheck: error: --numerics {args.numerics} applies to the "
                  f"built-in kernels; a user kernel is built as its device builds it",
                  file=sys.stderr)
            return 2
        try:
            rows = []
            for eta in args.eta:
                rows += check_user_kernel(args.user_kernel, args.function, args.against,
                                          eta=eta, n=args.n, device=args.device,
                                          timeout=args.timeout)
        except UserKernelError as exc:
            print(f"bdipole-cl crosscheck: error: {exc}", file=sys.stderr)
            return 1 if isinstance(exc, UserKernelRunError) else 2
    elif args.all_devices:
        rows = run_all_devices(args.eta, n=args.n, numerics=args.numerics)
    else:
        from ..device import get_runtime
        rt = get_runtime().with_numerics(args.numerics)
        rows = run_crosscheck(args.eta, n=args.n, device=rt)
        print(f"device: {rt.describe()}")
    print(format_rows(rows))
    return 1 if any(r.status == "FAIL" for r in rows) else 0
