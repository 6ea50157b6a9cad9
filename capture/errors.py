from devices.errors import WalkcapError


class CaptureError(WalkcapError):
    """A session or recording error; its message is shown to the user as is."""


class ConfigError(CaptureError):
    """The configuration file or a flag is wrong; the message names the key."""
