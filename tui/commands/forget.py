"""`walkcap forget SUBJECT`: remove what walkcap remembers of a subject

    walkcap forget S07

The form's memory (tui.remembered, ~/.config/walkcap/last_session.json) keeps each
subject's body data and the last form confirmed; this removes the subject's from it, at
once. Recordings are not touched.
"""

from __future__ import annotations

HELP = "remove what the session form remembers of a subject (body data, last form)"


def add_arguments(parser) -> None:
    parser.add_argument("subjects", nargs="+", metavar="SUBJECT", help="subject ids")


def run(args, config) -> int:
    from tui.remembered import forget, last_session_path

    path = last_session_path()
    for subject in args.subjects:
        removed = forget(subject, path)
        if removed:
            print(f"forgot {subject}: {' and '.join(removed)} ({path})")
        else:
            print(f"nothing remembered of {subject} ({path})")
    return 0
