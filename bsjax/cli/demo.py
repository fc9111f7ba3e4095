"""`bsjax demo`: the spoon case study of the thesis (§7.3), end to end (`bsjax.examples.demo`)."""

from __future__ import annotations

import argparse
from pathlib import Path


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bsjax demo", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bsjax-out", help="output folder (default ./bsjax-out)")
    parser.add_argument("--quick", action="store_true", help="small sizes (a 6³ jelly, short runs) for tests")
    args = parser.parse_args(argv)
    from bsjax.examples import demo

    out = Path(args.out)
    report = demo.run(out, quick=args.quick)
    files = sorted(p.name for p in out.iterdir())
    print(f"\nwrote {len(files)} files to {out}/: {', '.join(files)}")
    print(f"done in {report['total_seconds']:.1f} s")
    return 0
