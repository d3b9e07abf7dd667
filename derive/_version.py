"""The version of dq-derive (one place; the generated files' headers cite it)."""

__version__ = "0.2.0"
