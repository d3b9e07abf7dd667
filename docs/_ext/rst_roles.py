"""A griffe extension for the API reference (mkdocs.yml, mkdocstrings): the docstrings of
``derive`` are written for reading in the source and use reStructuredText roles
(:func:`name`, :class:`name`, ...) and ``::`` before literal blocks. Markdown shows those
literally; this turns a role into plain code (`name`) and ``text::`` into ``text:``. Only the
rendered site changes, never the docstrings."""

from __future__ import annotations

import re

from griffe import Extension

ROLE = re.compile(r":(?:func|class|meth|mod|attr|data|exc|obj|const|py:[a-z]+):`~?([^`]+)`")
LITERAL = re.compile(r"(\S)::[ \t]*$", re.M)
DOUBLE_BACKTICK = re.compile(r"``([^`]+)``")


class RstRoles(Extension):
    """Rewrite the RST markup of every docstring for Markdown."""

    def on_instance(self, *, obj, **kwargs) -> None:
        doc = getattr(obj, "docstring", None)
        if doc is None or not doc.value:
            return
        text = ROLE.sub(r"`\1`", doc.value)
        text = LITERAL.sub(r"\1:", text)
        doc.value = DOUBLE_BACKTICK.sub(r"`\1`", text)
