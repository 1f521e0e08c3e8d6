"""Layer 2: the app's long-lived parts (catalog, clip guesses, background work, job processes, uploads) and
``services``, the one object that holds them.

Imports only ``server.common`` and ``server.db``; never ``server.ops`` or ``server.api``."""
