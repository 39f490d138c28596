"""``python -m softbody sweep SWEEP.toml [--ray ADDRESS [--batch K]] [--out DIR] [--workers N] [--quiet]``:
the sweep command through the Python package (what ``softbody sweep --ray`` runs)."""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from typing import List, Optional

import softbody


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m softbody")
    commands = parser.add_subparsers(dest="command", required=True)
    p = commands.add_parser("sweep", help="run a parameter sweep (docs/guide/python-and-sweeps.md)")
    p.add_argument("sweep")
    p.add_argument("--out")
    p.add_argument("--ray", metavar="ADDRESS", help="run on the Ray cluster at ADDRESS ('auto', 'local', HOST:6379)")
    p.add_argument("--batch", type=int, metavar="K", help="with --ray: K runs per Ray task (default 1)")
    p.add_argument("--workers", type=int)
    p.add_argument("--quiet", "-q", action="store_true")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    try:
        records = softbody.sweep(
            args.sweep,
            out=args.out,
            executor="ray" if args.ray else "local",
            address=None if args.ray in (None, "auto") else args.ray,
            workers=args.workers,
            batch=args.batch,
            progress=not args.quiet,
        )
    except (softbody.SceneError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except softbody.SoftbodyError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    seconds = time.perf_counter() - started
    counts = Counter(r["status"] for r in records)
    if not args.quiet:
        print(
            f"{len(records)} runs recorded: {counts['ok']} ok, {counts['unstable']} unstable, "
            f"{counts['invalid']} invalid, {counts['failed']} failed in {seconds:.2f} s",
            file=sys.stderr,
        )
    return 1 if counts["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
