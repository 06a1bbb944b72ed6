"""The pages' templates (Jinja2, autoescaped): ``templates/*.html.j2`` in this package.

``base.html.j2`` is every page's frame: the doctype, the title, the shared styles (inline: a page
written by ``cab-report`` or ``cab-view`` is one self-contained file that opens offline), a nav
block, the body. The report (``report.html.j2``) and the attempt page (``attempt.html.j2``) extend
it, and so do the studio's templates (:mod:`cab_core.apps.studio`, through :func:`loader`).
HTML made in Python (a figure's SVG, a timeline entry) enters a template as :class:`Markup`, its
text escaped where it was made.
"""
from __future__ import annotations

from functools import lru_cache

from jinja2 import BaseLoader, ChoiceLoader, Environment, PackageLoader, StrictUndefined, select_autoescape
from markupsafe import Markup

__all__ = ["Markup", "env", "environment", "loader", "render"]

# the styles every page shares (the report's and the attempt page's own are added by their templates)
BASE_CSS = """body{font-family:sans-serif;margin:2em;max-width:1200px}table{border-collapse:collapse;margin:.5em 0}
td,th{border:1px solid #ccc;padding:3px 8px}th{background:#f3f3f3}.bad{color:#b00}.good{color:#070}"""


def loader() -> BaseLoader:
    """The loader of this package's templates (``base.html.j2``, ``report.html.j2``, ...)."""
    return PackageLoader("cab_core.analysis", "templates")


def environment(*first: BaseLoader, **options) -> Environment:
    """An environment whose templates may extend this package's (``first``: loaders searched before
    it, e.g. the studio's own templates); autoescaped, with the shared styles as ``base_css``."""
    e = Environment(loader=ChoiceLoader([*first, loader()]), autoescape=select_autoescape(["html", "j2"], default=True),
                    **options)
    e.globals["base_css"] = Markup(BASE_CSS)
    return e


@lru_cache(maxsize=1)
def env() -> Environment:
    """The environment of cab-report's and cab-view's pages (an undefined name is an error)."""
    return environment(undefined=StrictUndefined, trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)


def render(name: str, **ctx) -> str:
    """Template ``name`` rendered with ``ctx``."""
    return env().get_template(name).render(**ctx)
