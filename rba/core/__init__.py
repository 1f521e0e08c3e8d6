"""What every part of the library stands on: settings, where files live and how they are written, model artifacts,
per-key locks, and the registries (names -> import paths) of methods and domains."""
