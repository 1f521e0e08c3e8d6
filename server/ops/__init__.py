"""Layer 3: operations that take a ``Services`` (sessions, searches, views, labels, training jobs, export).

Imports ``server.common``, ``server.db`` and ``server.runtime``; never ``server.api``."""
