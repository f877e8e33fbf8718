"""The README and the pages under ``docs/`` are checked against the code they describe.

A user copies commands out of the documentation, so every ``ugvmap`` command line in it must
parse against the real command line (sub-commands, options, choices, arguments), every
``make`` target, ``bench/`` script (and the options given to it) and ``python -m`` module
must exist, every link between pages must resolve (anchors included), and every repository
file a page names must be there. Commands are parsed with click's own parser, never run, so
the check needs no database and takes a second.

The documentation's usage notation is understood: ``[...]`` marks optional parts (checked as
if given), ``a|b`` alternatives (each checked where the option has fixed choices or the
token names sub-commands), ``...`` repetition, and upper-case words and ``<...>`` are
placeholders.
"""

from __future__ import annotations

import importlib.util
import itertools
import re
import shlex
from collections.abc import Iterator
from pathlib import Path

import click
import pytest

from cli.main import main as ugvmap
from tests.conftest import REPO

PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
FENCE = re.compile(r"^ *```[^\n]*\n(.*?)^ *```", re.M | re.S)
INLINE = re.compile(r"(?<!`)`([^`]+)`(?!`)")
LINK = re.compile(r"(?<!!)\[[^\]\n]*\]\(([^)\s]+)\)")
PREFIXES = ("$ ", ".venv/bin/", "docker compose exec app ", "nice -n 10 ")
REPO_PATH = re.compile(r"^(?:app|cli|ingest|tests|bench|models|migrations|scripts)/[\w./-]+"
                       r"(?:::\w+)?$")


def code_blocks(text: str) -> list[str]:
    """The contents of the fenced code blocks."""
    return FENCE.findall(text)


def inline_spans(text: str) -> list[str]:
    """The inline code spans outside fenced blocks, a span broken over lines as one line."""
    return [re.sub(r"\s*\n\s*", " ", s) for s in INLINE.findall(FENCE.sub("", text))]


def block_lines(block: str) -> Iterator[str]:
    """A block's logical lines: backslash continuations joined, prompts and comments kept."""
    pending = ""
    for line in block.splitlines():
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        yield (pending + line).strip()
        pending = ""


def strip_prefixes(line: str) -> str:
    """A shell line as a user types it, without the prompt, venv path or container exec."""
    changed = True
    while changed:
        changed = False
        for prefix in PREFIXES:
            if line.startswith(prefix):
                line, changed = line[len(prefix):], True
    return line


def shell_words(line: str) -> list[str]:
    """Words of a shell line up to its comment (``<a value>`` is one word), or [] when it
    does not split."""
    try:
        return shlex.split(re.sub(r"<[^<>\n]+>", "VALUE", line), comments=True)
    except ValueError:
        return []


def usage_words(words: list[str]) -> list[str]:
    """Words with the usage notation removed: brackets and ellipses dropped."""
    cleaned = [w.replace("[", "").replace("]", "").removesuffix("...") for w in words]
    return [w for w in cleaned if w]


def is_placeholder(word: str) -> bool:
    """An upper-case word (NAME, W,S,E,N, DIR|x.zip) stands for the user's value."""
    return any(c.isupper() for c in word) and word == word.upper()


def check_command(line: str, require: bool = True) -> list[str]:
    """Problems of one ``ugvmap ...`` line against the real CLI ([] if it parses).

    ``require``: whether missing required arguments count (inline mentions in prose often
    name a command with only the option they talk about).
    """
    words = usage_words(shell_words(strip_prefixes(line)))
    if not words or words[0] != "ugvmap":
        return [f"not a ugvmap command: {line!r}"]
    return _check_path(ugvmap, ["ugvmap"], words[1:], line, require)


def _check_path(command: click.Command, path: list[str], words: list[str], line: str,
                require: bool) -> list[str]:
    """Walk sub-commands (each alternative of ``a|b``), then check the leaf's options."""
    if isinstance(command, click.Group) and words and not words[0].startswith("-"):
        problems = []
        for name in words[0].split("|"):
            sub = command.commands.get(name)
            if sub is None:
                problems.append(f"{' '.join(path)} has no command {name!r}: {line!r}")
            else:
                problems += _check_path(sub, [*path, name], words[1:], line, require)
        return problems
    if isinstance(command, click.Group) and not words:
        return []
    return _check_options(command, path, words, line, require)


def _check_options(command: click.Command, path: list[str], words: list[str], line: str,
                   require: bool) -> list[str]:
    """Parse the words with click's parser (no conversion, no callbacks) and check choices,
    argument counts and, if asked, required parameters."""
    where = f"{' '.join(path)}: {line!r}"
    options = {name: p for p in command.params if isinstance(p, click.Option)
               for name in (*p.opts, *p.secondary_opts)}
    problems = []
    concrete = []
    for i, word in enumerate(words):
        option = options.get(words[i - 1]) if i else None
        if (option is not None and not option.is_flag and isinstance(option.type, click.Choice)
                and not is_placeholder(word)):
            problems += [f"{words[i - 1]} has no choice {v!r} ({where})"
                         for v in word.split("|") if v not in option.type.choices]
        concrete.append(word.split("|")[0] if "|" in word and not is_placeholder(word) else word)
        takes_value = word in options and not options[word].is_flag and options[word].nargs == 1
        if takes_value and i + 1 < len(words) and words[i + 1].startswith("--"):
            concrete.append("VALUE")  # `[--host --port]` names options, their values elided
    ctx = click.Context(command, info_name=path[-1])
    try:
        values, args, _ = command.make_parser(ctx).parse_args(args=concrete)
    except click.UsageError as exc:
        return [*problems, f"{exc.format_message()} ({where})"]
    if "help" in values:
        return problems
    if args:  # what is left once every argument took its share
        problems.append(f"too many arguments {args} ({where})")
    if require:
        problems += [f"missing {p.name} ({where})" for p in command.params
                     if p.required and values.get(p.name) in (None, ())]
    return problems


def commands_in(text: str) -> Iterator[tuple[str, bool]]:
    """Every ``ugvmap`` command of a page: code-block lines (complete) and inline mentions
    (possibly partial)."""
    for block in code_blocks(text):
        for line in block_lines(block):
            if strip_prefixes(line).startswith("ugvmap"):
                yield line, True
    for span in inline_spans(text):
        if span.startswith("ugvmap ") or span == "ugvmap":
            yield span, False


def module_exists(name: str) -> bool:
    """Whether ``python -m name`` finds the module (its packages imported, not the module)."""
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:  # a parent package is missing
        return False


def make_targets() -> set[str]:
    """The targets the Makefile defines."""
    return set(re.findall(r"^([\w-]+):", (REPO / "Makefile").read_text(), re.M))


def check_other_commands(text: str) -> list[str]:
    """``make`` targets, ``bench/`` scripts with their options and ``python -m`` modules."""
    problems = []
    targets = make_targets()
    lines = [ln for b in code_blocks(text) for ln in block_lines(b)] + inline_spans(text)
    for line in lines:
        words = usage_words(shell_words(strip_prefixes(line)))
        if words[:1] == ["make"]:
            problems += [f"no make target {t!r}: {line!r}" for t in words[1:]
                         if not t.startswith("-") and "=" not in t and t not in targets]
        for i, word in enumerate(words):
            module = words[i + 1] if word == "-m" and i + 1 < len(words) else None
            if module and words[i - 1].endswith("python") and not module_exists(module):
                problems.append(f"no module {module!r}: {line!r}")
            if re.fullmatch(r"bench/[\w/]+\.py", word) and (REPO / word).is_file():
                source = (REPO / word).read_text()
                problems += [f"{word} has no option {w}: {line!r}" for w in words[i + 1:]
                             if w.startswith("--") and f'"{w.split("=")[0]}"' not in source]
    problems += [f"no file {name}" for name in sorted(set(re.findall(r"bench/[\w/]+\.py", text)))
                 if not (REPO / name).is_file()]
    return problems


def slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """The anchors of a page's headings (outside code blocks)."""
    text = FENCE.sub("", page.read_text())
    return {slug(h) for h in re.findall(r"^#{1,6} (.+)$", text, re.M)}


def check_links(page: Path, text: str) -> list[str]:
    """Relative links resolve to a file in the repository, and anchors to a heading."""
    problems = []
    for target in LINK.findall(FENCE.sub("", text)):
        if re.match(r"[a-z]+:", target):
            continue
        file_part, _, anchor = target.partition("#")
        linked = (page.parent / file_part).resolve() if file_part else page
        if not linked.exists() or REPO not in [linked, *linked.parents]:
            problems.append(f"{page.name}: link to a missing file {target!r}")
        elif anchor and linked.suffix == ".md" and anchor not in anchors(linked):
            problems.append(f"{page.name}: no heading #{anchor} in {linked.name}")
    return problems


def check_repo_paths(text: str) -> list[str]:
    """Repository files named in code spans exist (and a ``::test`` in them, as a function)."""
    problems = []
    for span in inline_spans(text):
        generated = "/." in span or "node_modules" in span  # made by a run or by setup
        if not REPO_PATH.match(span) or "*" in span or generated:
            continue
        name, _, test = span.partition("::")
        if not (REPO / name).exists():
            problems.append(f"no file {name}")
        elif test and not re.search(rf"^(async )?def {test}\b", (REPO / name).read_text(), re.M):
            problems.append(f"no test {test} in {name}")
    return problems


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_ugvmap_command_parses(page: Path) -> None:
    text = page.read_text()
    found = list(commands_in(text))
    problems = [p for line, complete in found for p in check_command(line, require=complete)]
    assert problems == []
    assert found or page.name in {"layout.md"}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_make_targets_bench_scripts_and_modules_exist(page: Path) -> None:
    assert check_other_commands(page.read_text()) == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_links_resolve(page: Path) -> None:
    assert check_links(page, page.read_text()) == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_repository_files_named_exist(page: Path) -> None:
    assert check_repo_paths(page.read_text()) == []


def test_readme_starts_with_the_two_commands() -> None:
    """CI and users run exactly these; they stay the first thing a reader sees."""
    first_block = code_blocks((REPO / "README.md").read_text())[0]
    assert [ln.split()[:2] for ln in first_block.splitlines()] == [["make", "demo"],
                                                                  ["make", "test"]]


def walkthrough_problems(text: str) -> list[str]:
    """What in a page's shell blocks would make its walk-through differ from its excerpts or
    leave files in the checkout: a written path (``--out``, ``mkdir``) relative to the
    checkout, or a ``curl`` whose excerpt shows the status line and headers without ``-i`` /
    ``-I`` asking for them."""
    problems = []
    for block in code_blocks(text):
        lines = list(block_lines(block))
        for n, line in enumerate(lines):
            words = shell_words(strip_prefixes(line))
            written = [w for i, w in enumerate(words) if i and words[i - 1] == "--out"]
            if words[:1] == ["mkdir"]:
                written += [w for w in words[1:] if not w.startswith("-")]
            problems += [f"{line!r} writes {w} inside the checkout" for w in written
                         if not w.startswith(("/", "$", "~", "FILE"))]
            shown = list(itertools.takewhile(lambda later: later.startswith("#"),
                                             lines[n + 1:]))
            if words[:1] == ["curl"] and any("HTTP/1." in later for later in shown) \
                    and not any(re.fullmatch(r"-[a-zA-Z]*[iI][a-zA-Z]*", w) for w in words):
                problems.append(f"{line!r} shows headers its curl does not ask for (-i)")
    return problems


def test_readme_walkthrough_keeps_the_checkout_clean_and_shows_what_it_asks_for() -> None:
    """Run after `make demo` in a fresh clone, the README's commands printed its excerpts and
    left `git status` clean; this keeps the two properties a page edit can break."""
    assert walkthrough_problems((REPO / "README.md").read_text()) == []
    bad = ("```sh\nmkdir -p maps/vegas\nugvmap export package --out mission.zip\n"
           "curl -X PATCH http://x/items/1\n#   HTTP/1.1 200 OK  ETag: \"2\"\n```\n")
    assert len(walkthrough_problems(bad)) == 3


@pytest.mark.parametrize("line", [
    "ugvmap ingest raster a.tif --layr drone",          # misspelt option
    "ugvmap layers lst",                                 # unknown sub-command
    "ugvmap export network city --format shp --out x",  # not a choice
    "ugvmap export network city --format geojson|shp --out x",
    "ugvmap route city --points",                        # option without its value
    "ugvmap extract-roads a.tif",                        # required --out missing
    "ugvmap network validate a b",                       # one argument too many
    "ugvmap serve [--host --prt]",                       # an option named in usage notation
])
def test_a_broken_command_is_caught(line: str) -> None:
    assert check_command(line) != []


@pytest.mark.parametrize("line", [
    "ugvmap export network NAME --format geojson|gpkg|osm --out FILE [--bbox W,S,E,N]",
    "$ ugvmap network validate ring-roads      # a comment",
    "ugvmap db stop|status",
    "ugvmap ingest raster ortho/*.tif --layer drone --title \"Drone survey\"",
    "ugvmap layers --help",
    "ugvmap serve [--host --port --workers] [--front-cache]",
])
def test_the_usage_notation_parses(line: str) -> None:
    assert check_command(line) == []


def test_a_broken_link_a_missing_script_and_a_missing_target_are_caught() -> None:
    page = REPO / "docs" / "x.md"
    assert check_links(page, "[a](nowhere.md) [b](routing.md#no-such-heading)") != []
    assert check_links(page, "[a](routing.md) [b](../Makefile) [c](https://example.org)") == []
    assert check_other_commands("```sh\nmake deploy\npython bench/nothing.py\n```") != []
    assert check_other_commands("`.venv/bin/python bench/ipm.py --no-such-option`") != []
    assert check_other_commands("`python -m no.such.module`") != []
    assert check_repo_paths("`tests/test_docs.py::test_no_such_test`") != []
