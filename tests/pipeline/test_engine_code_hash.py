"""A stage's code hash covers its own function and what it uses, not its whole module.

The stage functions live in one module (``pipeline.stages``); an edit to a later stage's
function must not rerun an earlier stage (a 15-minute acquisition), while an edit to a
helper or constant a stage uses must.  Here three toy stages live in one module file
that is edited between runs of the same workspace.
"""

from __future__ import annotations

import importlib.util
import json

import numpy as np

from pipeline.engine import run_pipeline
from pipeline.plan import Stage
from pipeline.workspace import function_code

SOURCE = '''
import numpy as np
from pipeline.workspace import save_npz

FACTOR = {factor}


def _scaled(values):
    return values * FACTOR


def first(ctx):
    CALLS.append("first")
    save_npz(ctx.out / "values.npz", values=_scaled(np.loadtxt(ctx.inputs[0])))


def second(ctx):
    CALLS.append("second")
    values = np.load(ctx.stage_path("first", "values.npz"))["values"]
    save_npz(ctx.out / "sum.npz", total=values.sum())


def third(ctx):
    CALLS.append("third")
    total = np.load(ctx.stage_path("second", "sum.npz"))["total"]
    ctx.out.write_text(f"{{float(total) {third_op}!r}}\\n")
'''


def _module(path, calls, factor=2.0, third_op="+ 0", head=""):
    path.write_text(head + SOURCE.format(factor=factor, third_op=third_op))
    spec = importlib.util.spec_from_file_location("toy_stages", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.CALLS = calls
    return module


def _stages(module):
    return [Stage("first", module.first, external=True),
            Stage("second", module.second, needs=("first",)),
            Stage("third", module.third, needs=("second",), target="third.txt")]


def test_an_edit_to_a_later_stage_does_not_rerun_earlier_ones(tmp_path):
    source, inputs, out = tmp_path / "toy_stages.py", tmp_path / "in.txt", tmp_path / "ws"
    np.savetxt(inputs, np.arange(5.0))
    calls: list[str] = []

    def run(**edit):
        calls.clear()
        run_pipeline([inputs], out, json.loads("{}"), stages=_stages(_module(source, calls,
                                                                               **edit)))
        return list(calls)

    assert run() == ["first", "second", "third"]
    assert run() == []
    # another stage's function edited, lines added above all of them: only it reruns
    edited = {"third_op": "+ 1", "head": "# a comment\n\n\ndef unrelated():\n    return 1\n"}
    assert run(**edited) == ["third"]
    assert float((out / "third.txt").read_text()) == 21.0  # 2 * (0+1+2+3+4) + 1
    # a constant the first stage's helper reads: it reruns, and what reads its output
    assert run(factor=3.0, **edited) == ["first", "second", "third"]
    assert float((out / "third.txt").read_text()) == 31.0


def test_function_code_follows_helpers_constants_and_imports(tmp_path):
    path = tmp_path / "toy_stages.py"
    base = _module(path, [])
    hashes = {name: function_code(getattr(base, name)) for name in ("first", "second", "third")}
    assert len(set(hashes.values())) == 3
    moved = _module(path, [], head="\n\n# moved down\n")
    assert {n: function_code(getattr(moved, n)) for n in hashes} == hashes
    factor = _module(path, [], factor=2.5)  # FACTOR: read by first through _scaled only
    assert function_code(factor.first) != hashes["first"]
    assert function_code(factor.second) == hashes["second"]
    assert function_code(factor.third) == hashes["third"]
