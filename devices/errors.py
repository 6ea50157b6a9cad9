"""Errors: one root for all of walkcap, and the devices' own.

`WalkcapError` lives here, in the lowest layer, so that every package's errors derive from
it (inference, capture and tui own theirs) and the CLI names one type when it prints a
user error as one line. A device error says whether the device was misconfigured or lost
while running.
"""


class WalkcapError(Exception):
    """Base of every walkcap error; its message is meant for the user as is."""


class DeviceError(WalkcapError):
    """Base of every device error; its message is shown to the user as is."""


class DeviceConfigError(DeviceError):
    """A configuration value the device or its simulator cannot take; names the key."""


class DeviceNotAvailable(DeviceError):
    """The backend cannot be used here (missing vendor SDK, no such port, unknown name)."""


class DeviceInitError(DeviceError):
    """The device answered wrongly or not at all while being configured."""


class DeviceOperationError(DeviceError):
    """The device failed while running (unplugged, silent, stalled)."""
