"""Layer 1: the database: SQL tables (``tables``, ``admin_tables``), the engine and the schema's migrations.

Imports only ``server.common`` (``tests/test_architecture.py`` checks the layers by folder)."""
