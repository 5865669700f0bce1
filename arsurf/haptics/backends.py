"""Haptic devices by name: which adapter each name is, and the one factory that makes them.

``virtual`` is the built-in simulated device (:class:`~arsurf.haptics.virtual_device.VirtualDevice`);
every other name is a vendor adapter (:data:`BACKENDS`), imported only when asked for (the vendor
package itself is loaded when the device opens, so a missing one is reported then, naming the
extra to install). What ``arsurf live --device NAME`` and ``arsurf devices`` use.

Examples
--------
>>> make_device("virtual", max_force=2.0).info.max_force
2.0
>>> make_device("haply", max_force=3.0, workspace=(0.2, 0.12, 0.15)).axes.spec
'x,y,z'
>>> make_device("falcon")
Traceback (most recent call last):
...
arsurf.errors.HapticsError: unknown device 'falcon'; devices are: virtual, forcedimension, haply, openhaptics (a ...
"""
from __future__ import annotations

import importlib
import inspect

from arsurf.errors import HapticsError

__all__ = ["BACKENDS", "DEVICES", "device_class", "device_options", "make_device"]

#: vendor backend name -> (adapter module, adapter class); each module also has ``probe()``
BACKENDS = {
    "forcedimension": ("arsurf.haptics.forcedimension", "ForceDimensionDevice"),
    "haply": ("arsurf.haptics.haply", "HaplyDevice"),
    "openhaptics": ("arsurf.haptics.openhaptics", "OpenHapticsDevice"),
}

#: every device name :func:`make_device` knows
DEVICES = ("virtual", *BACKENDS)


def device_class(name: str) -> type:
    """The :class:`~arsurf.haptics.device.Device` class called ``name`` (:data:`DEVICES`)."""
    if name == "virtual":
        from arsurf.haptics.virtual_device import VirtualDevice

        return VirtualDevice
    if name not in BACKENDS:
        raise HapticsError(f"unknown device {name!r}; devices are: {', '.join(DEVICES)} (a Novint Falcon is a "
                           "forcedimension device)")
    module, cls = BACKENDS[name]
    return getattr(importlib.import_module(module), cls)


def device_options(name: str) -> tuple[str, ...]:
    """The keyword options the device ``name`` takes (its constructor's arguments)."""
    params = inspect.signature(device_class(name)).parameters
    return tuple(p for p, v in params.items() if v.kind in (v.KEYWORD_ONLY, v.POSITIONAL_OR_KEYWORD))


def make_device(name: str, **options):
    """A device of backend ``name``, not opened, with the adapter's own keyword ``options``.

    Options are the adapter's constructor arguments (SI units: ``max_force`` N, ``workspace``
    (3,) m...); one it does not take is refused in one line listing those it does. Nothing is
    opened or loaded here: the vendor package and the device are reached by ``open()``.

    Raises
    ------
    HapticsError
        An unknown name or option, or an option value the adapter refuses.
    """
    takes = device_options(name)
    unknown = sorted(set(options) - set(takes))
    if unknown:
        raise HapticsError(f"device {name!r} takes no option {', '.join(unknown)}; it takes: {', '.join(takes)}")
    return device_class(name)(**options)
