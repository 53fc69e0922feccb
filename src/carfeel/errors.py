"""Errors carfeel raises on bad input. Each subclasses a builtin, so callers may catch either."""


class CarfeelError(Exception):
    """Base of every error carfeel raises on purpose; the CLI turns it into exit code 2."""


class PresetError(CarfeelError, ValueError):
    """A preset is missing, malformed, or has a value outside its physical range."""


class InputError(CarfeelError, ValueError):
    """A command-line argument, data file or packet is malformed or out of range."""
