"""Files written whole: a new file renamed over the old one, never a device node replaced."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from devices.errors import WalkcapError


class NotARegularFile(WalkcapError, FileExistsError):
    """The output path names a device, a pipe, a socket or a folder: renaming a new file
    over it would replace that node (/dev/null as a regular file breaks the machine)."""


def check_replaceable(path: str | os.PathLike) -> Path:
    """`path` if it is absent or a regular file (a link to one counts); NotARegularFile
    otherwise. Called before a file is written beside it and renamed into place."""
    path = Path(path)
    if not os.fspath(path):
        raise NotARegularFile("the output path is empty")
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return path
    except OSError:
        return path  # the write itself reports what is wrong with the path
    if not stat.S_ISREG(mode):
        what = "a folder" if stat.S_ISDIR(mode) else "not a regular file"
        raise NotARegularFile(
            f"{path} is {what}: walkcap writes its output as a new file and renames it into "
            "place, which would replace it; choose a file path"
        )
    return path
