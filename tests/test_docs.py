"""The docs say what the program does: the README's synopsis lists every flag `--help` has, and each
example output of the README and docs/datasets.md is what the command prints (timings aside). CPU."""

import argparse
import re
import shlex
from pathlib import Path

import pytest

from almsdm_warp.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def synopsis() -> dict[str, str]:
    """Command -> its lines in the README's synopsis (the ```bash block of "## Command line"), with the
    TISSUE line it names spelt out."""
    block = re.search(r"## Command line\n\n```bash\n(.*?)^```", README, flags=re.M | re.S).group(1)
    tissue = block[block.index("TISSUE =") :]
    commands: dict[str, str] = {}
    name = None
    for line in block[: block.index("TISSUE =")].splitlines():
        words = line.split()
        if words and words[0] == "almsdm":
            name = "palpate" if len(words) < 2 or words[1].startswith(("[", "-")) else words[1]
        if name is not None:
            commands[name] = commands.get(name, "") + line.replace("[TISSUE]", tissue) + "\n"
    return commands


def help_flags() -> dict[str, list[str]]:
    """Command -> the flags its --help lists (the first spelling of each; hidden old spellings left out)."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {name: [a.option_strings[0] for a in p._actions
                   if a.option_strings and a.help != argparse.SUPPRESS and a.option_strings[0] != "-h"]
            for name, p in sub.choices.items()}


@pytest.mark.parametrize("command", list(help_flags()))
def test_readme_synopsis_lists_every_flag_of_help(command):
    lines = synopsis()[command]
    missing = [f for f in help_flags()[command] if not re.search(rf"{re.escape(f)}(?![\w-])", lines)]
    assert missing == [], f"almsdm {command}: flags in --help but not in README.md's synopsis: {missing}"


def examples(text: str) -> list[tuple[str, list[str]]]:
    """(command, output lines) of each ```text block that starts with "$ almsdm ..." (or an unmarked one)."""
    blocks = re.findall(r"^```(?:text)?\n\$ (almsdm[^\n]*)\n(.*?)^```", text, flags=re.M | re.S)
    return [(cmd, out.rstrip("\n").splitlines()) for cmd, out in blocks]


TIMED = [(re.compile(r"^speed: .*"), "speed: T"),
         (re.compile(r"in [\d.]+ s \([\d,]+ region-steps/s"), "in T s (R region-steps/s"),
         (re.compile(r"in [\d.]+ s;"), "in T s;")]
"""What varies with the machine's load (wall times) -> a token, in both the expected and the printed line."""


def masked(line: str) -> str:
    for pattern, token in TIMED:
        line = pattern.sub(token, line)
    return line


def matches(expected: str, printed: str) -> bool:
    """`printed` is `expected`, where "..." in `expected` stands for any text and timings are masked."""
    pattern = ".*".join(re.escape(part) for part in masked(expected).split("..."))
    return re.fullmatch(pattern, masked(printed)) is not None


def assert_printed(expected: list[str], printed: list[str], command: str) -> None:
    """Every expected line (a lone "..." skips any lines) is printed, in order."""
    at = 0
    for line in expected:
        if line.strip() == "...":
            continue
        while at < len(printed) and not matches(line, printed[at]):
            at += 1
        assert at < len(printed), f"`{command}`: not printed: {line!r}\nprinted:\n" + "\n".join(printed)
        at += 1


README_EXAMPLES = examples(README)


def test_readme_has_its_example_outputs():
    assert [cmd.split()[:2] for cmd, _ in README_EXAMPLES] == [["almsdm", "--presses"], ["almsdm", "palpate"], ["almsdm", "sweep"]]


@pytest.mark.parametrize("command, expected", README_EXAMPLES, ids=[c.split()[1] for c, _ in README_EXAMPLES])
def test_readme_example_output_is_what_the_command_prints(command, expected, tmp_path, monkeypatch, capsys):
    """Run in a folder of its own (it writes out/...), from which the scenes are found by name."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").mkdir()
    assert main(shlex.split(command)[1:]) == 0
    assert_printed(expected, capsys.readouterr().out.splitlines(), command)


def test_datasets_doc_counts_are_the_examples():
    """docs/datasets.md's example: its items, presses and rows are those the spec plans (each press one row;
    tests/test_dataset.py checks a written table against its plan)."""
    from almsdm_warp.batch import dataset as ds

    text = (ROOT / "docs" / "datasets.md").read_text(encoding="utf-8")
    [(command, lines)] = [e for e in examples(text) if "--dataset" in e[0]]
    spec = ds.load_spec(ROOT / shlex.split(command)[shlex.split(command).index("--dataset") + 1])
    items = ds.plan_items(spec)
    presses = sum(len(i.plan.vertices) for i in items)
    said = re.search(r"dataset: (\d+) items .*, (\d+) presses", lines[0])
    rows = re.search(r"\((\d+) rows\)", lines[-1])
    assert (int(said.group(1)), int(said.group(2)), int(rows.group(1))) == (len(items), presses, presses)
