"""Griffe extension: the reST of photosurf's numpydoc docstrings as Markdown for mkdocstrings.

The docstrings are written for numpydoc (Sphinx roles, reST literals and math); mkdocstrings
renders Markdown.  Before rendering, each docstring's ``:func:`name``` (any role) becomes
``name`` in code, a double-backquoted literal single-backquoted, ``:math:`x``` becomes
``\\(x\\)`` and a ``.. math::`` block ``\\[ ... \\]`` (MathJax through ``pymdownx.arithmatex``),
and a ``[1]_`` citation mark is shown as ``[1]`` (escaped: not a Markdown link).  Nothing
else changes, and the sources are not touched.
"""

from __future__ import annotations

import re

import griffe

_ROLE = re.compile(r":(?:py:)?(?:func|meth|class|mod|data|attr|obj|exc|const|ref|term):`~?([^`]+)`")
_MATH_ROLE = re.compile(r":math:`([^`]+)`")
_LITERAL = re.compile(r"``([^`]+?)``")
_CITATION = re.compile(r"\[(\w+)\]_")
_MATH_BLOCK = re.compile(r"^([ ]*)\.\. math::[ ]*(.*)\n((?:\1[ ]+.*\n|[ ]*\n)*)", re.M)


def _math_block(match: re.Match) -> str:
    indent, first, body = match.group(1), match.group(2).strip(), match.group(3)
    lines = ([first] if first else []) + [line.strip() for line in body.splitlines()
                                          if line.strip()]
    return f"{indent}\\[\n{indent}" + f"\n{indent}".join(lines) + f"\n{indent}\\]\n\n"


def rst_to_markdown(text: str) -> str:
    """The reST constructs photosurf's docstrings use, as Markdown."""
    text = _MATH_BLOCK.sub(_math_block, text if text.endswith("\n") else text + "\n")
    text = _MATH_ROLE.sub(lambda m: f"\\\\({m.group(1)}\\\\)", text)
    text = _ROLE.sub(lambda m: f"`{m.group(1)}`", text)
    text = _LITERAL.sub(lambda m: f"`{m.group(1)}`", text)
    text = _CITATION.sub(lambda m: f"\\[{m.group(1)}\\]", text)
    return text.rstrip("\n")


class RstToMarkdown(griffe.Extension):
    """Rewrite every docstring's reST roles and math before mkdocstrings renders it."""

    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:  # noqa: ARG002
        if obj.docstring is not None:
            obj.docstring.value = rst_to_markdown(obj.docstring.value)
