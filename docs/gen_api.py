"""Write the API page of each public module of checks, matching, surface and pipeline lacking one.

A public module is a ``.py`` file of one of those packages whose name does not start with an
underscore; its page is ``docs/api/<package>/<module>.md`` holding the mkdocstrings directive
``::: <package>.<module>``.  ``tests/test_docs.py`` fails while a page is missing (or a page names
a module that no longer exists); this script is the fix it names.

Usage: ``python docs/gen_api.py`` from the repository root (``--check`` only lists what is missing
and exits 1 if anything is).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("checks", "matching", "surface", "pipeline")
API = ROOT / "docs" / "api"


def public_modules() -> list[str]:
    """Dotted names of the public modules, sorted."""
    names = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).glob("*.py")):
            if not path.name.startswith("_"):
                names.append(f"{package}.{path.stem}")
        for init in sorted((ROOT / package).glob("*/__init__.py")):   # a subpackage
            if not init.parent.name.startswith("_"):
                names.append(f"{package}.{init.parent.name}")
                names += [f"{package}.{init.parent.name}.{path.stem}"
                          for path in sorted(init.parent.glob("*.py"))
                          if not path.name.startswith("_")]
    return sorted(names)


def page_of(module: str) -> Path:
    *package, name = module.split(".")
    return API.joinpath(*package, f"{name}.md")


def expected_text(module: str) -> str:
    return f"# `{module}`\n\n::: {module}\n"


def untracked_modules() -> set[str]:
    """Modules git does not track yet (work in progress in this tree; a fresh clone has
    none): not held against the docs until committed.  Empty outside a git checkout."""
    try:
        out = subprocess.run(["git", "ls-files", "--others", "--exclude-standard", *PACKAGES],
                             cwd=ROOT, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return set()
    if out.returncode != 0:
        return set()
    return {name.removesuffix(".py").replace("/", ".") for name in out.stdout.split()
            if name.endswith(".py")}


def missing_pages() -> list[str]:
    return [m for m in public_modules() if not page_of(m).is_file()]


def stale_pages() -> list[Path]:
    """Pages under docs/api/<package>/ whose module is gone."""
    known = {page_of(m) for m in public_modules()}
    return sorted(p for package in PACKAGES for p in (API / package).glob("*.md")
                  if p not in known and p.name != "index.md")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="list missing pages, write nothing")
    args = parser.parse_args(argv)
    missing, stale = missing_pages(), stale_pages()
    if args.check:
        untracked = untracked_modules()
        for m in sorted(set(missing) & untracked):
            print(f"not committed yet, no page needed so far: {m}")
        missing = [m for m in missing if m not in untracked]
        for m in missing:
            print(f"missing API page: {page_of(m).relative_to(ROOT)} (module {m})")
        for p in stale:
            print(f"stale API page: {p.relative_to(ROOT)} (no such module)")
        return 1 if missing or stale else 0
    for m in missing:
        path = page_of(m)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(expected_text(m), encoding="utf-8")
        print(f"wrote {path.relative_to(ROOT)}")
    for p in stale:
        print(f"stale API page (remove it): {p.relative_to(ROOT)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
