"""A report's Markdown as one self-contained HTML page: figures embedded as data URIs, styles
inline, no script and nothing fetched, so that the page reads the same offline and attached
to an e-mail."""

import base64
import html
import mimetypes
import pathlib
import re

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #1d2731;
       max-width: 1100px; margin: 2em auto; padding: 0 1.5em; line-height: 1.5; }
h1 { border-bottom: 2px solid #2a9d8f; padding-bottom: .2em; }
h2 { margin-top: 1.8em; border-bottom: 1px solid #dde3e8; }
table { border-collapse: collapse; margin: 1em 0; font-size: .9em; display: block;
        overflow-x: auto; }
th, td { border: 1px solid #cfd8dc; padding: .3em .6em; text-align: left; vertical-align: top; }
th { background: #eef3f5; }
tr:nth-child(even) td { background: #f8fafb; }
img { max-width: 100%; height: auto; display: block; margin: 1em 0; }
code { background: #eef3f5; padding: 0 .25em; border-radius: 3px; }
pre code { display: block; padding: .6em; overflow-x: auto; }
""".strip()

_IMG = re.compile(r'(<img\b[^>]*?\bsrc=")([^"]+)(")')
_URL = re.compile(r'(\b(?:href|src)=")([^"]*)(")')
_SCHEME = re.compile(r"^\s*([a-zA-Z][a-zA-Z0-9+.-]*):")
_LINK = re.compile(r'(<a\b[^>]*?\bhref=")([^":#?]+)\.md(["#])')


def _safe_url(match: re.Match) -> str:
    """A link or image source that names a scheme other than http(s) or mailto (such as
    ``javascript:``, which a Markdown link made of a file's name could carry) becomes ``#``."""
    scheme = _SCHEME.match(html.unescape(match.group(2)).replace("\x00", ""))
    if scheme and scheme.group(1).lower() not in ("http", "https", "mailto"):
        return f"{match.group(1)}#{match.group(3)}"
    return match.group(0)


def _embed(match: re.Match, folder: pathlib.Path) -> str:
    source = html.unescape(match.group(2))
    path = (folder / source).resolve()
    if not path.is_relative_to(folder.resolve()) or not path.is_file():
        return match.group(0)  # not one of the report's own files: left as it is
    kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f"{match.group(1)}data:{kind};base64,{data}{match.group(3)}"


def markdown_to_html(text: str, folder, title: str) -> str:
    """The report's Markdown ``text`` as one HTML page. Images named relative to ``folder``
    (the report's folder) are embedded; links to other reports' ``.md`` files point to their
    ``.html`` pages."""
    import markdown

    folder = pathlib.Path(folder)
    converter = markdown.Markdown(extensions=["tables", "fenced_code"], output_format="html")
    # raw HTML in the text (a recording's name is a file's name) is shown, never interpreted
    converter.preprocessors.deregister("html_block")
    converter.inlinePatterns.deregister("html")
    body = _URL.sub(_safe_url, converter.convert(text))
    body = _IMG.sub(lambda m: _embed(m, folder), body)
    body = _LINK.sub(lambda m: f"{m.group(1)}{m.group(2)}.html{m.group(3)}", body)
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        '<meta name="generator" content="vfjax">\n'
        f"<title>{html.escape(title)}</title>\n<style>\n{_STYLE}\n</style>\n</head>\n"
        f"<body>\n<main>\n{body}\n</main>\n</body>\n</html>\n"
    )


def write_markdown_report(path, text: str) -> pathlib.Path:
    """Write the report ``text`` as Markdown to ``path`` (``.md``) and as one self-contained
    HTML page beside it (``.html``, titled by the text's first line, its heading), each
    atomically; returns the Markdown's path."""
    from .io import write_text

    path = pathlib.Path(path)
    title = text.split("\n", 1)[0].lstrip("#").strip()
    write_text(path, text)
    write_text(path.with_suffix(".html"), markdown_to_html(text, path.parent, title))
    return path
