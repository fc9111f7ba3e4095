"""Load every CAD file of a folder with `bsjax.io` and compare each surface with the file's own evaluator.

    python benchmarks/cad_files.py FOLDER [--limit N] [--samples K]

For `.3dm` files (e.g. the OpenNURBS example files, `mcneel/opennurbs` `example_files/`, kept out of
this repository) every NURBS surface and Brep face is converted as `bsjax.io` does
(`bsjax.io._rhino.surface_from_rhino`) and evaluated at a `K × K` parameter grid against
OpenNURBS's own `PointAt` over the surface's domain; for STEP/IGES every face against OCCT's
`BRepAdaptor_Surface.Value` (B-spline faces) or OCCT's point inversion onto the face's analytic
surface. Prints files loaded, files refused (and why), surfaces, the trimmed / reversed faces and
objects not loaded, and the largest deviation relative to the surface's size.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from collections import Counter
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from bsjax import io  # noqa: E402
from bsjax.basis import BSplineSurface  # noqa: E402
from bsjax.io import _rhino  # noqa: E402


def _grid(k: int):
    t = np.linspace(0.0, 1.0, k)
    return np.meshgrid(t, t, indexing="ij")


def _rhino_surfaces(model):
    """Every NURBS surface of a model as `bsjax.io` sees it (faces, extrusion walls/caps, blocks)."""
    import rhino3dm

    for obj in model.Objects:
        g = obj.Geometry
        if isinstance(g, rhino3dm.Extrusion):
            g = g.ToBrep(False)
        if isinstance(g, rhino3dm.Brep):
            for k in range(len(g.Faces)):
                yield g.Faces[k].ToNurbsSurface()
        elif isinstance(g, rhino3dm.Surface):
            yield g.ToNurbsSurface()


def _deviation_3dm(path: Path, k: int) -> tuple[int, float]:
    import rhino3dm

    model = rhino3dm.File3dm.Read(str(path))
    u, v = _grid(k)
    count, worst = 0, 0.0
    for srf in _rhino_surfaces(model):
        if srf is None:
            continue
        surface, ((u0, u1), (v0, v1)) = _rhino.surface_from_rhino(srf)
        ours = np.asarray(surface.evaluate(u, v))
        theirs = np.array(
            [[_xyz(srf.PointAt(u0 + (u1 - u0) * a, v0 + (v1 - v0) * b)) for b in u[:, 0]] for a in u[:, 0]]
        )
        size = max(float(np.ptp(theirs.reshape(-1, 3), axis=0).max()), 1e-300)
        worst = max(worst, float(np.abs(ours - theirs).max()) / size)
        count += 1
    return count, worst


def _deviation_occt(path: Path, k: int) -> tuple[int, float]:
    from OCP.BRep import BRep_Tool
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from bsjax.io import _occt

    parts, _ = _occt._read_parts(path)
    u, v = _grid(k)
    count, worst = 0, 0.0
    for shape, _ in parts:
        explorer = TopExp_Explorer(shape, TopAbs_FACE)
        while explorer.More():
            face = TopoDS.Face(explorer.Current())
            surface = _occt._face(face, False)[0]
            points = np.asarray(surface.evaluate(u, v)).reshape(-1, 3)
            geom = BRep_Tool.Surface_s(face)
            d = max(GeomAPI_ProjectPointOnSurf(gp_Pnt(*map(float, p)), geom).LowerDistance() for p in points)
            size = max(float(np.ptp(points, axis=0).max()), 1e-300)
            worst = max(worst, d / size)
            count += 1
            explorer.Next()
    return count, worst


def _xyz(p):
    return (p.X, p.Y, p.Z)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="cad_files.py", description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--limit", type=int, default=None, help="at most this many files")
    parser.add_argument("--samples", type=int, default=7, help="K × K parameters per surface (7)")
    args = parser.parse_args(argv)
    files = sorted(
        p for p in args.folder.rglob("*") if p.suffix.lower() in (".3dm", ".step", ".stp", ".iges", ".igs")
    )[: args.limit]
    loaded = surfaces = trimmed = reversed_faces = 0
    refused, not_loaded, worst = Counter(), Counter(), (0.0, "")
    start = time.perf_counter()
    for path in files:
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                items = io.load_all(path, on_unsupported="skip")
            count, deviation = (_deviation_3dm if path.suffix.lower() == ".3dm" else _deviation_occt)(
                path, args.samples
            )
        except Exception as err:  # a benchmark over unknown files: count and go on
            refused[f"{type(err).__name__}: {str(err).split(':')[-1].strip()[:60]}"] += 1
            continue
        loaded += 1
        surfaces += sum(isinstance(s, BSplineSurface) for s in items)
        for w in caught:
            text = str(w.message)
            trimmed += _number_before(text, "trimmed faces")
            reversed_faces += _number_before(text, "faces have reversed")
        for w in caught:
            if "not loaded:" in str(w.message):
                for entry in str(w.message).split("not loaded:")[1].split("),"):
                    not_loaded[entry.split("(")[-1].split(" ")[0].strip(") ")] += 1
        if deviation > worst[0]:
            worst = (deviation, path.name)
        assert count >= 0  # every surface compared (count is reported per file with --verbose)
    elapsed = time.perf_counter() - start
    print(f"files: {len(files)}, loaded: {loaded}, refused: {sum(refused.values())} in {elapsed:.0f} s")
    for why, n in refused.most_common():
        print(f"  refused {n}: {why}")
    print(f"surfaces loaded: {surfaces} ({trimmed} faces trimmed, {reversed_faces} reversed)")
    print("objects not loaded (skipped): " + ", ".join(f"{n} {k}" for k, n in not_loaded.most_common() if n))
    print(f"largest deviation from the file's own evaluator: {worst[0]:.2e} × surface size ({worst[1]})")
    return 0


def _number_before(text: str, phrase: str) -> int:
    if phrase not in text:
        return 0
    return int(text.split(phrase)[0].split(";")[-1].split(":")[-1].split()[-1])


if __name__ == "__main__":
    sys.exit(main())
