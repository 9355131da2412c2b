"""An mkdocs hook: the docstrings' Sphinx roles (:class:`Scene`, :func:`~.forces.grasp`) shown as
code, as Sphinx shows them, instead of as a literal ":class:" before the code.

Markdown renders :role:`target` as ``:role:<code>target</code>``; this drops the role and, as
Sphinx does, shows ``~a.b.c`` as ``c`` and a leading ``.`` (relative to the module) without it.
"""

from __future__ import annotations

import re
from typing import Any

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj|const):<code>([^<]*)</code>")


def _target(match: re.Match[str]) -> str:
    target = match.group(1)
    if target.startswith("~"):
        target = target[1:].rsplit(".", 1)[-1]
    return f"<code>{target.lstrip('.')}</code>"


def on_page_content(html: str, **kwargs: Any) -> str:
    """Every page's HTML, its Sphinx roles turned into plain code."""
    return ROLE.sub(_target, html)
