"""Which mock tracker an ``ndimock://`` URL names: the registry of mock NDI trackers by name
(:func:`register_robot`, :func:`register_device`), one default tracker per seed for a URL
without a name, the URL's fault and timing options, and the pyserial URL handler's package
(installed on import, so that :func:`serial.serial_for_url` finds ``ndimock://``)."""

from __future__ import annotations

import math
import re
import threading
from urllib.parse import parse_qs, urlsplit

import serial

from hexcal.mock_hw.ndi_tracker import URL_SCHEME, MockNDITracker
from hexcal.mock_hw.robot import MockRobot

_registry: dict[str, MockNDITracker] = {}
_defaults: dict[int, MockNDITracker] = {}
_registry_lock = threading.Lock()

_URL_FAULTS = {
    "drop": ("drop", 1.0),
    "garble": ("garble", 1.0),
    "crc": ("crc", 1.0),
    "truncate": ("truncate", 1.0),
    "nan": ("nan", 1.0),
    "delay_ms": ("delay_s", 1e-3),
    "jitter_ms": ("jitter_s", 1e-3),
}
URL_OPTIONS = ("seed", "frame_rate", *_URL_FAULTS)


def register_device(name: str, device: MockNDITracker) -> MockNDITracker:
    """Make ``device`` reachable as ``ndimock://<name>``."""
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise ValueError(f"mock tracker name {name!r}: use letters, digits, '_', '.' or '-'")
    with _registry_lock:
        _registry[name] = device
    device.name = name
    return device


def register_robot(name: str, robot: MockRobot, **kwargs) -> MockNDITracker:
    """A new mock tracker watching ``robot``, reachable as ``ndimock://<name>``; ``kwargs`` go
    to :class:`MockNDITracker`."""
    return register_device(name, MockNDITracker(robot, name=name, **kwargs))


def unregister(name: str) -> None:
    with _registry_lock:
        _registry.pop(name, None)


def get_device(name: str) -> MockNDITracker:
    with _registry_lock:
        try:
            return _registry[name]
        except KeyError:
            known = ", ".join(sorted(_registry)) or "none"
            raise KeyError(
                f"no mock tracker is registered as {name!r} (registered: {known}); call "
                f"hexcal.mock_hw.ndi_registry.register_robot({name!r}, robot) first"
            ) from None


def device_for_url(url: str) -> MockNDITracker:
    """The device an ``ndimock://`` URL names, with the URL's options applied. Raises
    ValueError (bad URL or option) or KeyError (no such name)."""
    parts = urlsplit(url)
    if parts.scheme.lower() != URL_SCHEME:
        raise ValueError(f"{url!r} is not an {URL_SCHEME}:// URL")
    name = (parts.netloc + parts.path).strip("/")
    options = {}
    for key, values in parse_qs(parts.query, keep_blank_values=True).items():
        if key not in URL_OPTIONS:
            raise ValueError(
                f"unknown option {key!r} in {url!r}; options: {', '.join(URL_OPTIONS)}"
            )
        try:
            options[key] = float(values[-1])
        except ValueError:
            raise ValueError(f"option {key}={values[-1]!r} in {url!r} is not a number") from None
        if not math.isfinite(options[key]) or options[key] < 0:
            raise ValueError(
                f"option {key}={values[-1]!r} in {url!r} must be a non-negative number"
            )
    if name:
        if "seed" in options:
            raise ValueError(
                f"'seed' applies to the default device only ({url!r}): seed the robot you register"
            )
        device = get_device(name)
    else:
        seed = int(options.get("seed", 0))
        with _registry_lock:
            if seed not in _defaults:
                _defaults[seed] = MockNDITracker(seed=seed, name=f"default (seed {seed})")
            device = _defaults[seed]
    if "frame_rate" in options:
        if options["frame_rate"] <= 0:
            raise ValueError(f"frame_rate must be positive in {url!r}")
        device.frame_rate_hz = options["frame_rate"]
    device.configure(
        **{_URL_FAULTS[k][0]: v * _URL_FAULTS[k][1] for k, v in options.items() if k in _URL_FAULTS}
    )
    return device


def install_url_handler() -> None:
    """Let :func:`serial.serial_for_url` find ``ndimock://`` (idempotent; done on import)."""
    if "hexcal.mock_hw" not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append("hexcal.mock_hw")


install_url_handler()
