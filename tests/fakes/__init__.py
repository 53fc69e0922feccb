"""Recorded fakes of the device libraries (python-evdev, pysdl2) for machines without them."""
