"""Boundaries with the outside world: presets, files, plots."""
