"""The README is a manual and docs/ its reference: short, self-contained, true to the code.

- README.md stays short (<= 450 lines) and no line of README.md or docs/ exceeds 1 000
  characters;
- README.md and docs/ cite papers by key (docs/references.md), never by a tracker number
  or a source file name, and point to nothing outside the repository;
- every ``python -m metro_atc ...`` command the README shows exists (``--help`` exits 0);
- every relative link of README.md and docs/ resolves, anchors included;
- docs/parameters.md lists exactly the parameters each node declares;
- every function docs/references.md names as implementing an equation exists.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import io
import re
import runpy
import shlex
import sys
import warnings
from pathlib import Path
from types import ModuleType
from typing import Iterator

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"

FORBIDDEN = {
    "a tracker number ('issue N')": re.compile(r"\bissues?\s+#?\d+", re.IGNORECASE),
    "a source file name ('seed 00N')": re.compile(r"\bseeds?\s+00\d", re.IGNORECASE),
    "a path outside the repository": re.compile(r"\.\./shared"),
}


def _doc_files() -> list[Path]:
    """README.md and every text file under docs/."""
    files = [README] + sorted(p for p in DOCS.rglob("*") if p.is_file()
                              and p.suffix in (".md", ".py", ".txt", ".yaml"))
    assert len(files) > 1, "docs/ is empty"
    return files


def test_readme_is_short() -> None:
    """A manual, not a diary: at most 450 lines."""
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= 450, f"README.md has {n} lines (at most 450)"


def test_no_line_over_1000_characters() -> None:
    """No paragraph written as one enormous line."""
    long = [f"{p.relative_to(ROOT)}:{i}" for p in _doc_files()
            for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
            if len(line) > 1000]
    assert not long, f"lines over 1 000 characters: {long}"


def test_citations_and_paths_stand_alone() -> None:
    """No 'issue N', no 'seed 00N', no '../shared' in README.md and docs/."""
    found = [f"{p.relative_to(ROOT)}:{i}: {what}: {m.group(0)!r}"
             for p in _doc_files()
             for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
             for what, rx in FORBIDDEN.items() for m in rx.finditer(line)]
    assert not found, "\n".join(found)


def readme_commands(text: str) -> list[list[str]]:
    """The distinct ``python -m metro_atc...`` commands of ``text``: module and sub-commands.

    A command is cut at its first option, placeholder or punctuation: ``python -m metro_atc
    bench lines --count N`` gives ``['metro_atc', 'bench', 'lines']``.
    """
    seen: dict[str, list[str]] = {}
    for m in re.finditer(r"python -m (metro_atc[\w.]*)((?:[ \t]+[a-z][a-z0-9_-]*)*)", text):
        words = [m.group(1)] + m.group(2).split()
        seen.setdefault(" ".join(words), words)
    return list(seen.values())


def _help(words: list[str]) -> int:
    """Exit code of ``python -m <words...> --help``, run in this process.

    ``python -m metro_atc bench`` alone is a group: its listing is ``--list``.
    """
    module, args = words[0], [*words[1:], "--list" if words[1:] == ["bench"] else "--help"]
    out = io.StringIO()
    argv = sys.argv
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            if module == "metro_atc":
                from metro_atc.cli import main
                return int(main(args))
            sys.argv = [module, *args]
            with warnings.catch_warnings():  # the module may already be imported by a test
                warnings.filterwarnings("ignore", r".*found in sys\.modules", RuntimeWarning)
                runpy.run_module(module, run_name="__main__", alter_sys=False)
            return 0
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.argv = argv


def test_readme_commands_exist() -> None:
    """Each command the README shows accepts ``--help`` (exit 0)."""
    cmds = readme_commands(README.read_text(encoding="utf-8"))
    assert ["metro_atc", "run"] in cmds
    bad = [" ".join(c) for c in cmds if _help(c) != 0]
    assert not bad, f"commands in README.md that do not exist: {bad}"


def test_readme_command_check_can_fail() -> None:
    """The check above rejects a command that does not exist."""
    cmds = readme_commands("run `python -m metro_atc bench no-such-bench --json` now")
    assert cmds == [["metro_atc", "bench", "no-such-bench"]]
    assert _help(cmds[0]) != 0


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"```.*?```", "", text, flags=re.DOTALL)
    return {_slug(m.group(1)) for m in re.finditer(r"^#+\s+(.*)$", text, re.MULTILINE)}


def _links(path: Path) -> Iterator[tuple[int, str]]:
    in_code = False
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if line.startswith("```"):
            in_code = not in_code
            continue
        if not in_code:
            for m in re.finditer(r"\]\(([^)\s]+)\)", line):
                yield i, m.group(1)


def test_links_resolve() -> None:
    """Every relative link of README.md and docs/*.md names an existing file and anchor."""
    bad = []
    for doc in [README, *sorted(DOCS.rglob("*.md"))]:
        for i, target in _links(doc):
            if re.match(r"^[a-z]+:", target):
                continue  # http(s), mailto: outside the repository, not checked here
            file_part, _, anchor = target.partition("#")
            dest = (doc.parent / file_part).resolve() if file_part else doc
            where = f"{doc.relative_to(ROOT)}:{i}: {target}"
            if not dest.exists():
                bad.append(f"{where} (no such file)")
            elif ROOT not in dest.parents and dest != ROOT:
                bad.append(f"{where} (outside the repository)")
            elif anchor and (dest.suffix != ".md" or anchor not in _anchors(dest)):
                bad.append(f"{where} (no such anchor)")
    assert not bad, "\n".join(bad)


def _gen_parameters() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gen_parameters",
                                                  DOCS / "gen_parameters.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclass looks its module up there
    spec.loader.exec_module(mod)
    return mod


def test_parameters_doc_lists_exactly_the_declared_parameters(ros_domain: int) -> None:
    """docs/parameters.md has one row per parameter each node holds, no more, no less.

    The nodes are built in-process on ``mini``; what they hold (``list_parameters``, rclpy's
    own parameters aside) is compared with the document's tables.
    """
    gen = _gen_parameters()
    doc = gen.documented((DOCS / "parameters.md").read_text(encoding="utf-8"))
    problems = []
    kinds = []
    for kind, decls, held in gen.node_parameters(ros_domain):
        kinds.append(kind)
        listed = doc.get(kind, set())
        assert {d.name for d in decls} == set(held), (kind, "declared outside declare()")
        if missing := set(held) - listed:
            problems.append(f"{kind}: not documented: {sorted(missing)}")
        if extra := listed - set(held):
            problems.append(f"{kind}: documented but not declared: {sorted(extra)}")
    if stray := set(doc) - set(kinds):
        problems.append(f"sections of no node: {sorted(stray)}")
    assert not problems, "\n".join(problems) + "\n(run: python docs/gen_parameters.py)"


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:  # a parent is a module, not a package
        return False


def test_referenced_functions_exist() -> None:
    """Each implementing function named in docs/references.md can be imported."""
    text = (DOCS / "references.md").read_text(encoding="utf-8")
    names = sorted(set(re.findall(r"`((?:core|bench|nodes)\.[A-Za-z0-9_.]+)`", text)))
    assert len(names) > 20
    missing = []
    for name in names:
        parts = f"metro_atc.{name}".split(".")
        for cut in range(len(parts), 1, -1):
            if _is_module(".".join(parts[:cut])):
                break
        obj: object = importlib.import_module(".".join(parts[:cut]))
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                missing.append(name)
                break
            obj = getattr(obj, attr)
    assert not missing, f"docs/references.md names what the code does not have: {missing}"


@pytest.mark.parametrize("key", ["Lin 2010a", "Lin 2010b", "Ke 2010", "ACTP n.d.",
                                 "Sheu 2011", "Li n.d."])
def test_each_citation_key_has_a_full_citation(key: str) -> None:
    """docs/references.md gives each key its citation paragraph."""
    text = (DOCS / "references.md").read_text(encoding="utf-8")
    assert f"**{key}** —" in text


def test_shlex_reads_the_readme_code_blocks() -> None:
    """The README's shell blocks are well-formed (balanced quotes)."""
    text = README.read_text(encoding="utf-8")
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.DOTALL):
        for line in block.splitlines():
            shlex.split(line, comments=True)
