"""Clips: MP4 encoding for browsers and the content-addressed clip cache."""
