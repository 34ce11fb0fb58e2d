"""Registering the workbench's Mitsuba plugins (once per variant)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .emitter import PLUGIN as LED_PLUGIN
from .emitter import make_led_class
from .integrator import PLUGIN as INTEGRATOR_PLUGIN
from .integrator import make_integrator_class
from .sensor import PLUGIN as CAMERA_PLUGIN
from .sensor import make_camera_class

if TYPE_CHECKING:  # mitsuba is loaded at run time in a chosen variant (``variant.load_mitsuba``), passed as ``mi``
    from types import ModuleType

_registered: dict[str, dict] = {}


def register_plugins(mi: ModuleType) -> dict:
    """Register LED emitter, distorted camera and multi-LED integrator for the active variant.

    Returns
    -------
    dict of plugin name to class (for isinstance checks)
    """
    variant = mi.variant()
    if variant not in _registered:
        led = make_led_class(mi)
        cam = make_camera_class(mi)
        integ = make_integrator_class(mi, led)
        mi.register_emitter(LED_PLUGIN, lambda props: led(props))
        mi.register_sensor(CAMERA_PLUGIN, lambda props: cam(props))
        mi.register_integrator(INTEGRATOR_PLUGIN, lambda props: integ(props))
        _registered[variant] = {LED_PLUGIN: led, CAMERA_PLUGIN: cam, INTEGRATOR_PLUGIN: integ}
    return _registered[variant]
