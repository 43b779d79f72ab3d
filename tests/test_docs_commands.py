"""The commands the READMEs show parse with the CLIs they name, so documentation cannot drift from the flags."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from lerobot_skillret.kitchen.generate import build_parser as generate_parser
from lerobot_skillret.pipeline.config import PipelineConfig
from lerobot_skillret.retrieval.cli import build_parser as retrieve_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("README.md", "configs/README.md", "lerobot_skillret/kitchen/README.md")


def documented_commands(program: str) -> list[tuple[str, list[str]]]:
    """(doc, argv after the program) for each line of a ```bash block that runs `program`."""
    found = []
    for doc in DOCS:
        for block in re.findall(r"```bash\n(.*?)```", (ROOT / doc).read_text(), flags=re.S):
            for line in block.replace("\\\n", " ").splitlines():
                line = re.sub(r"\s#.*$", "", line)  # trailing comment
                line = re.sub(r"\[--[^\]]*\]", "", line)  # an optional flag shown in brackets
                words = shlex.split(line)
                if program in words:
                    found.append((doc, words[words.index(program) + 1 :]))
    return found


PARSERS = {"skillret-generate": generate_parser, "skillret-retrieve": retrieve_parser}


def test_the_readmes_show_how_to_generate_data_and_retrieve():
    assert len(documented_commands("skillret-generate")) >= 4 and documented_commands("skillret-retrieve")


@pytest.mark.parametrize(
    "program, doc, argv", [(program, *found) for program in PARSERS for found in documented_commands(program)]
)
def test_the_documented_generate_and_retrieve_commands_parse(program, doc, argv):
    PARSERS[program]().parse_args(argv)  # argparse exits with the bad flag named


@pytest.mark.parametrize("doc, argv", documented_commands("skillret-pipeline"))
def test_the_documented_pipeline_commands_parse(doc, argv):
    command, rest = argv[0], argv[1:]
    if command == "table":
        assert rest[:1] == ["--results"] and (ROOT / rest[1]).is_dir(), f"{doc}: {argv}"
        return
    assert command in ("run", "heldout") and rest[0] == "--config", f"{doc}: {argv}"
    PipelineConfig.from_args(ROOT / rest[1], rest[2:])  # every key checked, as the CLI does before any stage
