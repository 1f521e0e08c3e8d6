"""Layer 4: HTTP: the routes, their dependencies, the admin gate and the body limit. ``server.main`` builds the app."""
