"""What a robot is: descriptions, identity, geometry, URDF input and output.

The URDF reader (:mod:`derive.model.urdf`: lxml, yourdfpy) is heavy and only a URDF path needs
it, so :mod:`derive.model.robot` reaches it as this package's attribute ``urdf``, imported on
first use (PEP 562): loading a YAML or library robot does not import it (docs/architecture.md,
"Light import").
"""


def __getattr__(name: str):
    if name == "urdf":
        import derive.model.urdf     # sets the attribute: this runs once
        return derive.model.urdf
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
