"""Identification from measured logs, and validation of the models against them."""
