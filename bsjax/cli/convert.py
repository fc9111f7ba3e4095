"""`bsjax convert IN OUT`: convert surfaces between .json, .3dm and mesh formats (`bsjax.io`)."""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bsjax convert", description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("target")
    parser.add_argument("--samples", type=int, default=82, help="grid size for mesh output")
    args = parser.parse_args(argv)
    from bsjax import io

    surfaces = io.load_all(args.source)
    io.save(surfaces, args.target, args.samples, args.samples)
    print(f"{args.source} → {args.target}: {len(surfaces)} surface(s)", file=sys.stderr)
    return 0
