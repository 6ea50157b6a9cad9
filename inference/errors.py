class InferenceError(Exception):
    """Bad model file, bad score file, bad parameters; shown to the user as is."""
