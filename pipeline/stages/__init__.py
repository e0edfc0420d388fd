"""The thesis's stages, one module per section of chapters 3-5 (docs/architecture.md maps equations to functions)."""
