"""ffviz: the CLI and the visual-debugger side (Rerun recorder, blueprint, viewer, figures)."""

__version__ = "0.1.0"
