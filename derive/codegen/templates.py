"""The jinja2 environment over ``templates/``, shared by every emitter (kernels, reports)."""

from __future__ import annotations

import jinja2

from derive.codegen.formats import TEMPLATE_DIR


def template_environment() -> jinja2.Environment:
    """jinja2 environment over the project's ``templates/`` folder."""
    if TEMPLATE_DIR.is_dir():
        loader = jinja2.FileSystemLoader(str(TEMPLATE_DIR))
    else:  # installed from a wheel: templates are packaged as derive.templates
        loader = jinja2.PackageLoader("derive", "templates")
    return jinja2.Environment(loader=loader, keep_trailing_newline=True, trim_blocks=True,
                              lstrip_blocks=True, undefined=jinja2.StrictUndefined,
                              autoescape=False)
