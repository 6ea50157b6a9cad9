"""The live screen's widgets, one module each; they show what they are given, nothing more."""
