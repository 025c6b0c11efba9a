"""One CLI style: every command's --help has examples that the real parser accepts, every output
is -o/--output (never positional), and ``bag convert IN OUT`` still works with a note."""
from __future__ import annotations

import argparse
import shlex

import pytest

from mocapgraph.bag.reader import BagReader
from mocapgraph.cli import build_parser, main
from mocapgraph.cli.examples import EXAMPLES, leaves

PARSER = build_parser()
LEAVES = leaves(PARSER)


@pytest.mark.parametrize("path", sorted(LEAVES))
def test_every_command_has_examples_that_parse(path):
    p = LEAVES[path]
    assert "examples:" in p.format_help(), f"mocapgraph {path} --help has no examples"
    for args, _ in EXAMPLES[path]:
        ns = PARSER.parse_args(path.split() + shlex.split(args))  # SystemExit (a failure) if it does not parse
        assert callable(ns.func)


@pytest.mark.parametrize("path", sorted(LEAVES))
def test_outputs_are_dash_o(path):
    for a in LEAVES[path]._actions:
        if a.dest in ("output", "out", "outfile", "dst"):
            assert a.option_strings[:2] == ["-o", "--output"] or set(a.option_strings) == {"-o", "--output"}, path
        if not a.option_strings and a.help is not argparse.SUPPRESS:
            assert a.dest not in ("output", "out", "dst"), f"{path}: positional output {a.dest}"


def test_bag_convert_takes_dash_o_and_still_reads_the_old_form(capture, tmp_path, capsys):
    def run(*args):
        code = main(["bag", "convert", *map(str, args)])
        return code, capsys.readouterr().err

    code, err = run(capture.rom, "-o", tmp_path / "new.mcap")
    assert code == 0 and "note:" not in err, err
    code, err = run(capture.rom, tmp_path / "old.mcap")
    assert code == 0 and "now given as -o" in err
    with BagReader(tmp_path / "old.mcap") as a, BagReader(tmp_path / "new.mcap") as b:
        assert a.summary().count == b.summary().count > 0
    code, err = run(capture.rom)
    assert code == 2 and "no output: bag convert IN -o OUT" in err
    code, err = run(capture.rom, tmp_path / "a.mcap", "-o", tmp_path / "b.mcap")
    assert code == 2 and "two outputs" in err
