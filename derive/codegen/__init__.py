"""From derived expressions to source files, and the loader of the emitted kernels.

The emitters (:mod:`derive.codegen.emit`, :mod:`derive.codegen.fk`: sympy) and the templates
(:mod:`derive.codegen.templates`: jinja2) are needed only to derive kernels or to build the
CPython extension, so :mod:`derive.codegen.loader` reaches them as this package's attributes
``emit`` and ``templates``, imported on first use (PEP 562): loading shipped or cached kernels
does not import them (docs/architecture.md, "Light import").
"""


def __getattr__(name: str):
    if name == "emit":
        import derive.codegen.emit       # sets the attribute: this runs once
        return derive.codegen.emit
    if name == "templates":
        import derive.codegen.templates
        return derive.codegen.templates
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
