"""Presets that ship with carfeel, one folder per kind of model."""
