"""The documentation points at things that exist: every relative link in README.md and docs/
resolves to a file (and a heading, for an anchor), every `walkcap` command in README's
command table is one the CLI parses (and every command the CLI parses is in the table),
every repository path or module the documents cite is in the repository, the README stays
an introduction (300 lines at most), and the Python example of docs/recordings.md runs."""

import argparse
import re
from pathlib import Path

import pytest

from tests.recording_fixtures import write_recording
from tui.cli import build_parser

ROOT = Path(__file__).parent.parent
DOCS = sorted((ROOT / "docs").glob("*.md"))
DOCUMENTS = [ROOT / "README.md", ROOT / "ARCHITECTURE.md", ROOT / "CHANGELOG.md", *DOCS]
# Written by `walkcap config` on the configuration's own branch; its links are checked
# whenever it is in the tree.
GENERATED = {ROOT / "docs" / "configuration.md"}

FENCE = re.compile(r"^```.*?^```", re.S | re.M)
CODE_SPAN = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.M)
REPO_PATH = re.compile(r"^(?:capture|devices|inference|tui|tests|docs|examples|\.ci)/[\w./-]*$")
MODULE = re.compile(r"^(?:capture|devices|inference|tui|tests)(?:\.\w+)+$")


def name(path: Path) -> str:
    return str(path.relative_to(ROOT))


def prose(text: str) -> str:
    """The text without fenced code and code spans: links are only in prose."""
    return CODE_SPAN.sub("", FENCE.sub("", text))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    return {slug(h) for h in HEADING.findall(FENCE.sub("", path.read_text()))}


@pytest.mark.parametrize("doc", DOCUMENTS, ids=name)
def test_every_relative_link_resolves(doc):
    assert doc.is_file(), f"{name(doc)} is missing"
    broken = []
    for target in LINK.findall(prose(doc.read_text())):
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        dest = (doc.parent / file).resolve() if file else doc
        if not dest.exists():
            if dest in GENERATED:
                continue
            broken.append(f"{target}: no such file")
        elif anchor and anchor not in anchors(dest):
            broken.append(f"{target}: no heading #{anchor} in {name(dest)}")
    assert not broken, f"{name(doc)}: " + "; ".join(broken)


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def parsed_commands() -> set[tuple[str, ...]]:
    """Every command the CLI parses: each top-level command, or each verb of one with verbs."""
    commands = set()
    for command, parser in subcommands(build_parser()).items():
        verbs = subcommands(parser)
        commands |= {(command, verb) for verb in verbs} if verbs else {(command,)}
    return commands


def table_commands() -> set[tuple[str, ...]]:
    """The command in the first cell of each row of README's command table: the words after
    `walkcap` up to the first argument (FILE, PORT, ...)."""
    section = re.search(r"^## Commands\n(.*?)^## ", (ROOT / "README.md").read_text(), re.S | re.M)
    assert section, "README has a Commands section"
    commands = set()
    for cell in re.findall(r"^\| `walkcap ([^`]+)` \|", section.group(1), re.M):
        words = []
        for word in cell.split():
            if not re.fullmatch(r"[a-z][a-z-]*", word):
                break
            words.append(word)
        commands.add(tuple(words))
    return commands


def test_readme_command_table_is_the_cli():
    table, cli = table_commands(), parsed_commands()
    assert table, "README's command table names commands"
    assert not table - cli, f"in README's table but not in the CLI: {sorted(table - cli)}"
    assert not cli - table, f"in the CLI but not in README's table: {sorted(cli - table)}"


def cited_paths(text: str) -> set[str]:
    """Repository paths and module names in code spans and code blocks."""
    cited = set()
    for span in CODE_SPAN.findall(text) + FENCE.findall(text):
        for token in re.split(r"[\s`,;()]+", span):
            token = token.rstrip(".:")
            if REPO_PATH.match(token) or MODULE.match(token):
                cited.add(token)
    return cited


def layout_paths(text: str) -> set[str]:
    """The files and folders drawn in ARCHITECTURE.md's layout tree (an indented block:
    two spaces a level, a folder ends in /)."""
    section = re.search(r"^## Layout\n(.*?)^## ", text, re.S | re.M)
    if not section:
        return set()
    paths, stack = set(), []
    for line in section.group(1).splitlines():
        m = re.match(r"^    ( *)([\w.-]+(?:/|\.\w+))(?:\s|$)", line)
        if not m:
            continue
        depth = len(m.group(1)) // 2
        stack[depth:] = [m.group(2).rstrip("/")]
        paths.add("/".join(stack))
    return paths


def module_file(parts: list[str]) -> Path | None:
    base = ROOT.joinpath(*parts)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def defines(module: Path, attr: str) -> bool:
    """The module defines, assigns or imports `attr` at its top level (an import of several
    names lists one a line)."""
    a = re.escape(attr)
    pattern = rf"^(?:def|class)\s+{a}\b|^{a}\s*[:=]|^(?:from|import)\s.*\b{a}\b|^\s+{a},?$"
    return bool(re.search(pattern, module.read_text(), re.M))


def exists(cited: str) -> bool:
    if MODULE.match(cited):  # a module, or one attribute of a module
        parts = cited.split(".")
        if module_file(parts):
            return True
        module = module_file(parts[:-1])
        return module is not None and defines(module, parts[-1])
    path = ROOT / cited
    # a module is named with or without .py: `inference/evaluation` is the module or package
    return path.exists() or path.with_suffix(".py").is_file()


@pytest.mark.parametrize("doc", DOCUMENTS, ids=name)
def test_every_cited_path_exists(doc):
    text = doc.read_text()
    cited = cited_paths(text) | (layout_paths(text) if doc.name == "ARCHITECTURE.md" else set())
    missing = sorted(c for c in cited if not exists(c))
    assert not missing, f"{name(doc)} cites what the repository lacks: {missing}"


def test_readme_stays_an_introduction():
    lines = (ROOT / "README.md").read_text().count("\n")
    assert lines <= 300, f"README.md has {lines} lines; the manual belongs in docs/"


def test_the_python_example_of_docs_recordings_runs(tmp_path, monkeypatch, capsys):
    (example,) = re.findall(
        r"^```python\n(.*?)^```", (ROOT / "docs" / "recordings.md").read_text(), re.S | re.M
    )
    (path,) = re.findall(r'open_recording\("([^"]+)"\)', example)
    monkeypatch.chdir(tmp_path)
    (tmp_path / path).parent.mkdir(parents=True)
    write_recording(tmp_path / path, seconds=0.5)
    exec(compile(example, "docs/recordings.md", "exec"), {})
    assert capsys.readouterr().out.startswith("S07 ")  # the session's subject it prints


def test_the_methods_table_of_docs_analysis_is_the_method_table():
    from inference.fusion import METHOD_TABLE

    text = (ROOT / "docs" / "analysis.md").read_text()
    section = text[text.index("## Fusion methods") :]
    rows = re.findall(
        r"^\| `([^`]+)` \| (.+) \|$", section.split("\n\n| method |")[1].split("\n\n")[0], re.M
    )
    assert rows == [(m.name, m.doc) for m in METHOD_TABLE]
