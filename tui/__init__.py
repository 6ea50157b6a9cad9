"""The user's side: the `walkcap` command line and the Textual terminal UI."""
