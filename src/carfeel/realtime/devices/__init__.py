"""Force-feedback devices behind one small protocol (`base.Device`).

The virtual devices and the replay device ship with carfeel; the evdev (Linux) and SDL2 backends
import their libraries only when opened, so nothing heavy sits on the loop's import path.
"""
