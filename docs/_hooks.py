"""mkdocs hook: the command-line page's reference is the parser's own help, rendered at build
time, so that it cannot fall behind the code."""

import argparse
import os

MARKER = "<!-- vfjax-cli-help -->"


def _help_blocks() -> str:
    from vfjax.cli import build_parser

    os.environ["COLUMNS"] = "96"  # argparse wraps to the terminal's width
    parser = build_parser()
    parser.prog = "vfjax"
    blocks = ["## `vfjax`", "", "```text", parser.format_help().rstrip(), "```", ""]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                blocks += [f"## `vfjax {name}`", "", "```text", sub.format_help().rstrip()]
                blocks += ["```", ""]
    return "\n".join(blocks)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER in markdown:
        return markdown.replace(MARKER, _help_blocks())
    return markdown
