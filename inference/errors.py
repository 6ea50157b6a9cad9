from devices.errors import WalkcapError


class InferenceError(WalkcapError):
    """Bad model file, bad score file, bad parameters; shown to the user as is."""
