"""Layer 0: what every layer of the server uses: the app's settings, its one error body, and the rules of feedback.

Imports nothing from ``server`` outside this folder."""
