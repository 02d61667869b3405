"""The plan of ``photosurf run``: each stage's declared modules cover the code it runs.

A stage's code hash comes from the modules it declares (``Stage.modules`` and
``kind_modules``, followed through their imports), not from where its function's
import statements sit.  What the function really uses is read here from the source of
``pipeline.stages``: the imports inside it and inside the module's helpers it calls,
and the module-level imported names it refers to.  Every such photosurf module must lie
in the code closure of the declaration, or a change to it would not rerun the stage.
"""

from __future__ import annotations

import ast
import inspect

import pytest

from pipeline import plan, stages
from pipeline.workspace import _module_file, code_files

OWN = ("matching", "surface", "pipeline")


def _module_imports(tree: ast.Module) -> dict[str, str]:
    """Module-level imported local names -> the module they come from."""
    names: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.Import):
            for alias in node.names:
                names[alias.asname or alias.name.partition(".")[0]] = alias.name
        elif isinstance(node, ast.ImportFrom) and node.module:
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                names[alias.asname or alias.name] = full if _module_file(full) else node.module
    return names


def used_modules(func) -> set[str]:
    """photosurf modules a function of ``pipeline.stages`` (and the helpers it calls) uses."""
    tree = ast.parse(inspect.getsource(inspect.getmodule(func)))
    defs = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
    imported = _module_imports(tree)
    seen, todo, used = set(), [func.__name__], set()
    while todo:
        name = todo.pop()
        if name in seen or name not in defs:
            continue
        seen.add(name)
        for node in ast.walk(defs[name]):
            if isinstance(node, ast.Import):
                used.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module:
                for alias in node.names:
                    full = f"{node.module}.{alias.name}"
                    used.add(full if _module_file(full) else node.module)
            elif isinstance(node, ast.Name):
                if node.id in defs:
                    todo.append(node.id)
                elif node.id in imported:
                    used.add(imported[node.id])
    return {m for m in used if m.partition(".")[0] in OWN}


def _closure(modules) -> set[str]:
    root = _module_file("pipeline").parents[1]
    return {p.relative_to(root).with_suffix("").as_posix().replace("/", ".")
            for p in code_files(modules)}


CASES = [(stage, kind) for stage in plan.STAGES for kind in
         ([k for k in ("cloud", "stereo", "folder")] if stage.kind_modules else [None])]


@pytest.mark.parametrize(("stage", "kind"), CASES,
                         ids=[f"{s.name}-{k}" if k else s.name for s, k in CASES])
def test_declared_modules_cover_what_the_stage_function_uses(stage, kind, tmp_path):
    declared = stage.code_modules(kind or "cloud", tmp_path)
    closure = {m.removesuffix(".__init__") for m in _closure(declared)}
    used = used_modules(stage.func)
    if kind is not None:  # the kind's branch: the other kinds' modules need not be declared
        others = {m for k, mods in stage.kind_modules if k != kind for m in mods}
        used -= others - set(declared)
    assert used, stage.name
    assert used <= closure, f"{stage.name}: not declared: {sorted(used - closure)}"


def test_the_parser_sees_function_level_and_module_level_imports():
    # the smooth stage imports pipeline.bezier_surface inside the function and uses the
    # module-level artifacts: both count, wherever the import statement sits
    used = used_modules(stages.smooth)
    assert {"pipeline.bezier_surface", "pipeline.artifacts", "pipeline.errors"} <= used


def test_stage_order_and_plans():
    assert tuple(s.name for s in plan.STAGES) == plan.STAGE_ORDER
    assert [s.name for s in plan.plan("cloud")] == list(plan.STAGE_ORDER[1:])
    assert [s.name for s in plan.plan("scene")] == list(plan.STAGE_ORDER)
    for stage in plan.STAGES:  # every declared module exists: nothing "not there yet"
        for module in stage.modules + tuple(m for _, ms in stage.kind_modules for m in ms):
            assert _module_file(module) is not None, module


def test_acquire_sees_the_sections_asked_and_no_other_sections_key():
    """The working resolution depends on sections.count / spacing: they are acquire's
    parameters (a change reruns it); the sections' other keys are not."""
    from pipeline.config import defaults
    from pipeline.engine import _stage_params
    from pipeline.plan import STAGES

    acquire = next(s for s in STAGES if s.name == "acquire")
    config = defaults()
    params = _stage_params(acquire, config, "folder")
    assert params["sections"] == {"count": 0, "spacing": 0.0}
    assert params["acquire"] == config["acquire"]
    config["sections"]["axis"] = "z"
    assert _stage_params(acquire, config, "folder") == params
    config["sections"]["count"] = 40
    assert _stage_params(acquire, config, "folder")["sections"]["count"] == 40
    # a stereo pair or a cloud: no working resolution, the sections are not its business
    assert set(_stage_params(acquire, config, "stereo")) == {"acquire"}
    assert set(_stage_params(acquire, config, "cloud")) == {"acquire"}
