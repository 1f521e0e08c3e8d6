"""An RBA Studio domain in its own package: rba finds it through the entry point in ``pyproject.toml``."""
