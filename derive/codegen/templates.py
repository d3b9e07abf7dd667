"""The jinja2 environment over ``templates/``, shared by every emitter (kernels, reports)."""

from __future__ import annotations

from pathlib import Path

import jinja2


def template_environment() -> jinja2.Environment:
    """jinja2 environment over the project's ``templates/`` folder."""
    source = Path(__file__).resolve().parents[2] / "templates"
    if source.is_dir():
        loader = jinja2.FileSystemLoader(str(source))
    else:  # installed from a wheel: templates are packaged as derive.templates
        loader = jinja2.PackageLoader("derive", "templates")
    return jinja2.Environment(loader=loader, keep_trailing_newline=True, trim_blocks=True,
                              lstrip_blocks=True, undefined=jinja2.StrictUndefined,
                              autoescape=False)
