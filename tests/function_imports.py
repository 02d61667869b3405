"""The rule for imports inside functions (docs/architecture.md, "Imports inside functions").

An import inside a function of ``matching``, ``surface`` or ``pipeline`` is allowed for:

1. a heavy third-party library a command may never need (:data:`HEAVY`), and OpenCV in
   ``pipeline``;
2. an optional dependency (:data:`OPTIONAL`), so that its absence is an error only where it is
   used;
3. a photosurf module imported by a ``pipeline`` module (a stage or command imports the code it
   runs when it runs).

Everything else -- the standard library, numpy, scipy, a photosurf module imported inside a
function of ``matching`` or ``surface`` -- belongs at the top of the module.  The imports of that
kind still in the tree are counted per module in :data:`LEFT`: a module may not gain one, and the
counts only shrink (a module below its count is named, to lower it).  Run by ``make lint``
(``python tests/function_imports.py``) and by ``tests/test_imports.py``.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("checks", "matching", "surface", "pipeline")
#: Heavy libraries a command may never need: imported where they are used.
HEAVY = {"open3d", "pycolmap", "dask", "distributed", "tqdm"}
#: Optional dependencies: their absence is a one-line error only where they are used.
OPTIONAL = {"OCP", "ezdxf"}

#: Imports inside functions against the rule still in the tree, per module (only shrinks).
LEFT: dict[str, int] = {
    "matching.contours": 3, "matching.ici": 1, "matching.masks": 2,
    "matching.precision": 1, "matching.rectify": 1, "matching.roi": 2, "matching.scale": 3,
    "matching.scheduler": 2, "matching.second_order": 1, "matching.sfm": 1,
    "matching.sfm_refine": 4, "pipeline.acquisition": 1,
    "pipeline.cmd_run": 1, "pipeline.match_maps": 4, "pipeline.mesh_io": 1, "pipeline.report": 1,
    "pipeline.bezier_surface": 2, "surface._blas": 2,
    "surface.general_mesh": 7, "surface.measure": 7, "surface.metrics": 1,
    "surface.outliers": 1,
    "surface.stitch.caps": 2
}


def allowed(module: str, imported: str) -> bool:
    """Whether ``module`` (dotted) may import ``imported`` inside a function."""
    top = imported.split(".")[0]
    package = module.split(".")[0]
    if top in HEAVY or top in OPTIONAL:
        return True
    if package == "pipeline" and (top == "cv2" or top in PACKAGES):
        return True
    return False


def function_imports(path: Path) -> list[tuple[int, str]]:
    """``(line, imported module)`` of every import inside a function of the file."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for inner in ast.walk(node):
            if isinstance(inner, ast.Import):
                found += [(inner.lineno, alias.name) for alias in inner.names]
            elif isinstance(inner, ast.ImportFrom) and inner.level == 0 and inner.module:
                found.append((inner.lineno, inner.module))
    return sorted(set(found))


def against_the_rule(root: Path = ROOT) -> dict[str, list[tuple[int, str]]]:
    """Per module, the imports inside functions the rule does not allow."""
    out = {}
    for package in PACKAGES:
        for path in sorted([*(root / package).glob("*.py"), *(root / package).glob("*/*.py")]):
            parts = path.relative_to(root).with_suffix("").parts   # a subpackage's modules too
            module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            bad = [(line, name) for line, name in function_imports(path)
                   if not allowed(module, name)]
            if bad:
                out[module] = bad
    return out


def problems(root: Path = ROOT) -> tuple[list[str], list[str]]:
    """``(errors, notes)``: modules with more imports against the rule than :data:`LEFT`
    allows them (each import named), and modules whose count in it can be lowered."""
    found = against_the_rule(root)
    errors, notes = [], []
    for module, bad in found.items():
        if len(bad) > LEFT.get(module, 0):
            where = ", ".join(f"line {line} {name}" for line, name in bad)
            errors.append(f"{module}: {len(bad)} imports inside functions against the rule "
                          f"(allowed {LEFT.get(module, 0)}): {where}")
    for module, count in LEFT.items():
        if len(found.get(module, ())) < count:
            notes.append(f"{module}: {len(found.get(module, ()))} left, LEFT says {count}: "
                         "lower it")
    return errors, notes


def main() -> int:
    errors, notes = problems()
    for line in errors + notes:
        print(line)
    total = sum(len(v) for v in against_the_rule().values())
    print(f"imports inside functions against the rule: {total} "
          f"({'broken' if errors else 'kept'}; docs/architecture.md, Imports inside functions)")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
