#!/usr/bin/env python3
"""Where a cold compile of the filter kernels goes: ``mavahrs warm-up`` (or one part of it) in this process,
with the CPU time of every kernel's compilation (its own, the kernels it compiles on the way left out) and
the signatures it was compiled for.

Usage (an empty cache, so that everything compiles; never the cache other processes use)::

    NUMBA_CACHE_DIR=$(mktemp -d) python3 scripts/profile_compile.py --json compile.json
    NUMBA_CACHE_DIR=$(mktemp -d) python3 scripts/profile_compile.py --part eskf

numba announces each compilation (``numba:compile``) around the typing, lowering and LLVM of one
specialisation; a kernel compiled while another compiles (a callee that is not inlined) is nested in it
and its time is taken out of the caller's.  Kernels inlined at numba's IR level (``@kernel(inline=True)``)
are part of their caller's time.  Results in docs/reliability.md, "Suite time on a fresh machine".
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from collections import defaultdict
from typing import Any


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--part", help="one part of the warm-up (mavahrs.warmup.PARTS) instead of all of it")
    parser.add_argument("--json", metavar="FILE", help="every kernel: [own CPU s, with callees s, signatures]")
    parser.add_argument("--top", type=int, default=40, help="kernels listed (default 40)")
    args = parser.parse_args(argv)

    from numba.core import event

    from mavahrs.filters.jit import quick_start

    quick_start()
    stack: list[list[Any]] = []
    own: dict[str, float] = defaultdict(float)
    total: dict[str, float] = defaultdict(float)
    signatures: dict[str, list[str]] = defaultdict(list)

    class _Listener(event.Listener):  # type: ignore[misc]
        def on_start(self, ev: Any) -> None:
            stack.append([ev.data["dispatcher"], time.process_time(), 0.0])

        def on_end(self, ev: Any) -> None:
            dispatcher, t0, nested = stack.pop()
            dt = time.process_time() - t0
            py = dispatcher.py_func
            name = f"{py.__module__}.{py.__qualname__}"
            total[name] += dt
            own[name] += dt - nested
            signatures[name].append(str(ev.data.get("args")))
            if stack:
                stack[-1][2] += dt

    event.register("numba:compile", _Listener())
    t0 = time.monotonic()
    if args.part:
        from mavahrs.warmup import warm_up_part

        warm_up_part(args.part)
    else:
        from mavahrs.warmup import warm_up

        warm_up()
    usage = resource.getrusage(resource.RUSAGE_SELF)
    rows = sorted(own, key=lambda k: -own[k])
    print(f"wall {time.monotonic() - t0:.1f} s, CPU {usage.ru_utime + usage.ru_stime:.1f} s; compiling "
          f"{sum(own.values()):.1f} s: {len(rows)} kernels, {sum(len(v) for v in signatures.values())} signatures")
    print(" own s  with callees s  signatures  kernel")
    for k in rows[: args.top]:
        print(f"{own[k]:6.2f}  {total[k]:14.2f}  {len(signatures[k]):10d}  {k}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({k: [own[k], total[k], signatures[k]] for k in rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
