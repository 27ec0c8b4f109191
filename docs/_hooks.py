"""mkdocs hooks: the command-line page's reference is the parser's own help, rendered at build
time so that it cannot fall behind the code; and the pages' formulas are MathML, rendered by
the browser itself, so that the site needs no script from elsewhere and reads offline."""

import argparse
import html
import os
import re

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


#: pymdownx.arithmatex's generic output: \( ... \) in a span, \[ ... \] in a div
_MATH = re.compile(r'<(span|div) class="arithmatex">\s*\\([(\[])(.*?)\\[)\]]\s*</\1>', re.S)


def _mathml(match: re.Match) -> str:
    from latex2mathml.converter import convert

    display = "block" if match.group(2) == "[" else "inline"
    return convert(html.unescape(match.group(3)), display=display)


def on_page_content(content: str, page, config, files) -> str:
    return _MATH.sub(_mathml, content)
