"""Device errors: a misconfiguration differs from a device lost while running."""


class DeviceError(Exception):
    """Base of every device error; its message is shown to the user as is."""


class DeviceConfigError(DeviceError):
    """A configuration value the device or its simulator cannot take; names the key."""


class DeviceNotAvailable(DeviceError):
    """The backend cannot be used here (missing vendor SDK, no such port, unknown name)."""


class DeviceInitError(DeviceError):
    """The device answered wrongly or not at all while being configured."""


class DeviceOperationError(DeviceError):
    """The device failed while running (unplugged, silent, stalled)."""
