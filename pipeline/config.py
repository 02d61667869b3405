"""Configuration: defaults, a TOML file, and ``--set`` overrides, resolved in that order.

Every parameter of ``photosurf run`` has its default in ``pipeline/defaults.toml``
(one place).  A config file (``--config FILE``) and command-line assignments
(``--set section.key=value``, the value written as a TOML value: ``3``,
``0.5``, ``true``, ``"auto"``, ``[1, 0, 0]``; a bare word is taken as a
string) override it.  Unknown sections or keys, values of the wrong type and
values out of range (:data:`RANGES`) are errors naming the key and the value,
so that a typo never passes silently and never creates a workspace.
A table whose default is empty (``{}``) is free-form: any key is accepted there
(used for the scene-recipe overrides).
"""

from __future__ import annotations

import copy
import math
import os
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from importlib import resources

import tomli_w

from pipeline import limits
from pipeline.errors import InputError
from pipeline.guards import load_toml

#: Keys that take a value of the default's type *or* one of these words (``axis`` also a
#: vector ``[x, y, z]``): ``axis = "auto"``, ``smoothing = "auto"``, ``level = "auto"``.
FLEXIBLE = {
    "sections.axis": ("x", "y", "z", "auto", "data"),
    "curves.smoothing": ("auto",),
    "smooth.level": ("auto", "adaptive"),
    "acquire.densify": ("auto",),
    "curves.open": ("auto",),
}

#: FLEXIBLE keys whose default is a word: an example of the other values they take
#: (``smooth.level`` defaults to "adaptive" and takes an integer level too;
#: ``acquire.densify`` defaults to "auto" and takes true / false).
FLEXIBLE_EXAMPLE = {"smooth.level": 1, "acquire.densify": True, "curves.open": True}

#: Parameters that take one of a fixed set of words (lists: every element must be one).
CHOICES = {
    "acquire.interpolation": ("bilinear", "bicubic", "spline"),
    "acquire.masks": ("auto", "folder", "none"),
    "curves.parametrisation": ("uniform", "centripetal", "chordal"),
    "sections.projection": ("surface", "axis"),
    "export.formats": ("ply", "obj", "stl", "gltf", "glb", "step", "iges"),
}


def _positive(v) -> bool:
    return math.isfinite(v) and v > 0


def _non_negative(v) -> bool:
    return math.isfinite(v) and v >= 0


#: Ranges checked when a value is set (a word of FLEXIBLE passes): key -> (test, wording).
#: Checked up front so that an invalid configuration never creates a workspace.
RANGES = {
    "acquire.patch": (lambda v: v >= 3 and v % 2 == 1, "an odd integer >= 3"),
    "acquire.spacing": (lambda v: v >= 1, ">= 1"),
    "acquire.max_iter": (lambda v: v >= 1, ">= 1"),
    "acquire.shift_stop_px": (_positive, "> 0"),
    "acquire.min_correlation": (lambda v: -1 <= v <= 1, "in [-1, 1]"),
    "acquire.sigma0_factor": (_positive, "> 0"),
    "acquire.min_texture_snr": (_non_negative, ">= 0"),
    "acquire.max_reprojection_px": (_non_negative, ">= 0 (0: off)"),
    "sections.count": (lambda v: v == 0 or v >= 2, ">= 2 (0: from the point density)"),
    "sections.spacing": (_non_negative, "> 0 (0: from the point density)"),
    "sections.thickness": (_non_negative, "> 0 (0: from the spacing)"),
    "curves.n": (lambda v: v == 0 or v >= 4, ">= 4 (0: from the data)"),
    "curves.smoothing": (_non_negative, ">= 0 or 'auto'"),
    "curves.outlier_threshold": (_positive, "> 0"),
    "curves.min_loop_points": (lambda v: v == 0 or v >= 4, ">= 4 (0: from curves.smoothing)"),
    "smooth.level": (lambda v: 0 <= v <= 6, "0..6, 'auto' or 'adaptive'"),
    "smooth.tolerance": (_non_negative, ">= 0 (0: from the data)"),
    "smooth.size_tolerance": (_non_negative, ">= 0 (0: the dense stitched mesh's own error)"),
    "report.width": (lambda v: v >= 16, ">= 16 pixels"),
    "report.height": (lambda v: v >= 16, ">= 16 pixels"),
    "report.tau_rel": (_positive, "> 0"),
    "report.samples": (lambda v: v >= 100, ">= 100"),
    "executor.workers": (lambda v: v >= 1, ">= 1"),
}


#: Parameters whose size has a documented limit (:mod:`pipeline.limits`): key -> limit key.
LIMITED = {
    "acquire.max_iter": "iterations",
    "sections.count": "sections.count",
    "curves.n": "ring.points",
    "executor.workers": "workers",
    "report.samples": "file.elements",
}


def _check_range(dotted: str, value, origin: str) -> None:
    rule = RANGES.get(dotted)
    if rule is None or isinstance(value, str | bool) or not isinstance(value, int | float):
        return
    test, wording = rule
    if not test(value):
        raise InputError(f"{origin}: {dotted} must be {wording}, got {value!r}")
    if dotted in LIMITED:
        limits.check(LIMITED[dotted], value, where=f"{origin}: {dotted}")
    if dotted in ("report.width", "report.height"):
        limits.check("render.pixels", 4 * value * value, where=f"{origin}: {dotted} (squared)")


def defaults() -> dict:
    """The parsed ``pipeline/defaults.toml`` (a fresh copy)."""
    text = resources.files("pipeline").joinpath("defaults.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def load_file(path: str | os.PathLike) -> dict:
    """Read a TOML config file; errors name the file and the TOML problem."""
    return load_toml(path, "config file")


def parse_assignment(text: str, form: str = "section.key=value",
                     min_parts: int = 2) -> tuple[list[str], object]:
    """Split ``"section.key=value"`` into ``(["section", "key"], value)``: every ``--set``.

    The value is parsed as a TOML value; when that fails (a bare word such as
    ``auto``) it is kept as a string.  ``form`` names the expected form in the errors
    (``photosurf synth``'s ``TABLE.KEY=VALUE``); the key needs ``min_parts`` dotted
    parts, none empty (``photosurf run``: a section and a key; ``synth``: one is enough).
    """
    if "=" not in text:
        raise InputError(f"--set {text!r}: expected {form}")
    key, raw = text.split("=", 1)
    path = [part.strip() for part in key.strip().split(".")]
    if len(path) < min_parts or not all(path):
        example = " (e.g. sections.count=24)" if min_parts >= 2 else ""
        raise InputError(f"--set {text!r}: the key must be {form.split('=')[0]}{example}")
    return path, parse_value(raw, f"--set {key.strip()}")


def parse_value(raw: str, origin: str):
    """One TOML value (``3``, ``0.5``, ``true``, ``"auto"``, ``[1, 0, 0]``); a bare word is
    kept as a string.

    The text must be exactly one value: a line break (which could start a new
    table or key and inject it into the configuration) or a value followed by
    more TOML is an ``InputError`` naming ``origin`` (the key).
    """
    if any(c in raw for c in "\n\r\x00") or not raw.strip().isprintable():
        raise InputError(f"{origin}: the value must be one TOML value on one line, got {raw!r}")
    raw = raw.strip()
    try:
        parsed = tomllib.loads(f"v = {raw}")
    except tomllib.TOMLDecodeError:
        if any(c in raw for c in "=[]{}\"'"):  # TOML syntax that did not parse: not a word
            raise InputError(f"{origin}: not a TOML value: {raw!r}") from None
        return raw
    except RecursionError:
        raise InputError(f"{origin}: the value is nested too deeply") from None
    if list(parsed) != ["v"]:
        raise InputError(f"{origin}: the value must be one TOML value, got {raw!r}")
    return parsed["v"]


def _type_ok(default, value) -> tuple[bool, object]:
    if isinstance(default, bool):
        return isinstance(value, bool), value
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool), value
    if isinstance(default, float):
        if isinstance(value, int | float) and not isinstance(value, bool):
            return True, float(value)
        return False, value
    return isinstance(value, type(default)), value


def _free_tables(table: Mapping, prefix: str = "") -> frozenset[str]:
    """Dotted names of the tables whose default is empty (free-form)."""
    found = set()
    for key, value in table.items():
        if isinstance(value, Mapping):
            found |= {f"{prefix}{key}"} if not value else _free_tables(value, f"{prefix}{key}.")
    return frozenset(found)


_FREE = _free_tables(defaults())


def _merge(base: dict, update: Mapping, origin: str, prefix: str = "") -> None:
    """Merge ``update`` into ``base`` (in place), checking keys and types against ``base``."""
    for key, value in update.items():
        dotted = f"{prefix}{key}"
        if key not in base:
            known = ", ".join(sorted(base)) or "none"
            what = "section" if not prefix else "parameter"
            raise InputError(f"{origin}: unknown {what} {dotted!r} (known: {known})")
        default = base[key]
        if isinstance(default, dict):
            if not isinstance(value, Mapping):
                raise InputError(f"{origin}: {dotted} must be a table, got {value!r}")
            if dotted in _FREE:  # free-form table: deep-merge without checks
                deep_update(default, value)
            else:
                _merge(default, value, origin, f"{dotted}.")
            continue
        if dotted in FLEXIBLE:
            example = FLEXIBLE_EXAMPLE.get(dotted, default)
            ok, converted = _type_ok(example, value)
            ok = ok and not isinstance(example, str)  # a word must be one of the words
            vector = (isinstance(value, list) and len(value) == 3 and
                      all(isinstance(v, int | float) and not isinstance(v, bool) for v in value))
            if not (ok or value in FLEXIBLE[dotted] or (dotted == "sections.axis" and vector)):
                words = " or ".join(repr(w) for w in FLEXIBLE[dotted])
                kind = "[x, y, z] or " if dotted == "sections.axis" else \
                    f"{type(example).__name__} (like {example!r}) or "
                raise InputError(f"{origin}: {dotted} must be {kind}{words}, got {value!r}")
            if dotted == "sections.axis" and vector and not ok:
                # a direction: scaled by its largest component (no overflow of 1e308**2)
                largest = max(abs(float(v)) for v in value)
                if not all(math.isfinite(float(v)) for v in value) or largest == 0:
                    raise InputError(f"{origin}: sections.axis must be a finite, non-zero "
                                     f"direction [x, y, z], got {value!r}")
                value = [float(v) / largest for v in value]
            base[key] = converted if ok else value
            _check_range(dotted, base[key], origin)
            continue
        ok, converted = _type_ok(default, value)
        if not ok:
            raise InputError(f"{origin}: {dotted} must be {type(default).__name__} "
                             f"(like {default!r}), got {value!r}")
        allowed = CHOICES.get(dotted)
        if allowed is not None:
            for word in converted if isinstance(converted, list) else [converted]:
                if word not in allowed:
                    raise InputError(f"{origin}: {dotted} {word!r}: choose from "
                                     f"{', '.join(allowed)}")
        _check_range(dotted, converted, origin)
        base[key] = converted


def deep_update(base: dict, update: Mapping, dotted: bool = False) -> None:
    """Merge nested ``update`` into ``base`` in place (no checks on keys or types): the one
    merge of configurations, batch ``set`` tables and scene recipes.

    With ``dotted``, a string key ``"cameras.width"`` stands for ``{"cameras": {"width": ...}}``
    (tables made on the way; a part that exists and is no table is an ``InputError``).
    """
    for key, value in update.items():
        node, leaf = base, key
        if dotted and isinstance(key, str):
            *parts, leaf = key.split(".")
            for part in parts:
                node = node.setdefault(part, {})
                if not isinstance(node, dict):
                    raise InputError(f"override {key!r}: {part!r} is not a table")
        if isinstance(value, Mapping) and isinstance(node.get(leaf), dict):
            deep_update(node[leaf], value, dotted)
        else:
            node[leaf] = copy.deepcopy(value)


def resolve(config_file: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
            assignments: Iterable[str] = (),
            overrides: Mapping | None = None,
            overrides_origin: str = "batch manifest") -> dict:
    """Resolve the configuration: defaults, ``config_file``, ``overrides``, then ``--set``.

    Parameters
    ----------
    config_file : path or sequence of paths, optional
        TOML file(s) with the same sections as ``defaults.toml``, applied in order.
    assignments : iterable of str
        ``"section.key=value"`` strings from ``--set``.
    overrides : mapping, optional
        A nested dict applied after the file (used by ``photosurf batch``).
    overrides_origin : str
        Where ``overrides`` come from, for error messages (the manifest's path).

    Returns
    -------
    dict
        The full parameter set, every section present.
    """
    config = defaults()
    files = [config_file] if isinstance(config_file, str | os.PathLike) else (config_file or [])
    for path in files:
        _merge(config, load_file(path), str(path))
    if overrides:
        _merge(config, overrides, overrides_origin)
    for text in assignments:
        path, value = parse_assignment(text)
        nested: dict = {}
        cursor = nested
        for part in path[:-1]:
            cursor = cursor.setdefault(part, {})
        cursor[path[-1]] = value
        _merge(config, nested, f"--set {text}")
    return config


def dumps(config: Mapping) -> str:
    """The configuration as TOML text (what ``OUTDIR/config.toml`` holds)."""
    header = "# photosurf: resolved configuration of this run (defaults + --config + --set)\n"
    return header + tomli_w.dumps(dict(config))
