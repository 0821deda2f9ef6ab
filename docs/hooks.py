"""mkdocs hook (mkdocs.yml ``hooks:``): Sphinx roles in the API pages, shown as code.

The package's docstrings cross-reference with reST roles (``:func:`run_agents```,
``:mod:`~vdbejax.engine.lockstep```), which Markdown renders as ``:func:`` followed by
code. On the API pages this drops the role and, as Sphinx does, shows only the last
component of a name written with a leading ``~``. It changes nothing else.
"""
from __future__ import annotations

import re

_ROLE = re.compile(r":(?:py:)?(?:func|mod|class|data|attr|meth|exc|obj|const):"
                   r"<code>(~?)([^<]*)</code>")


def _code(match: re.Match[str]) -> str:
    tilde, name = match.groups()
    return f"<code>{name.rsplit('.', 1)[-1] if tilde else name}</code>"


def on_page_content(html: str, page, config, files) -> str:
    if not page.file.src_uri.startswith("api/"):
        return html
    return _ROLE.sub(_code, html)
