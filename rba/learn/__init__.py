"""Learned models: ζσ ranker, global reward rθ (and later local reward, PbRL)."""
