"""MkDocs hook: replace `<!-- cli-help -->` in a page with the help of `rigidjax` and of each
of its commands.

The text comes from the command's own argument parser, so the page cannot drift from the code.
If the parser cannot be built (the CLI module moved or failed to import), the page says how to
see the help instead, and the build goes on.
"""

from __future__ import annotations

import logging
import os

MARKER = "<!-- cli-help -->"
log = logging.getLogger("mkdocs.hooks.cli_help")


def _help() -> str:
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "96"  # argparse wraps to the terminal width: fix it for the page
    try:
        import argparse

        from rigidjax.cli.main import _parser

        parser = _parser()
        texts = [f"$ rigidjax --help\n{parser.format_help()}"]
        for action in parser._actions:  # the subcommands' own parsers
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    texts.append(f"$ rigidjax {name} --help\n{sub.format_help()}")
        return "\n".join(texts)
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def on_page_markdown(markdown: str, **kwargs) -> str:
    if MARKER not in markdown:
        return markdown
    try:
        text = f"```text\n{_help().rstrip()}\n```"
    except Exception as e:  # noqa: BLE001 - the site must build even if the CLI is broken
        log.info("cli_help hook: could not build the parser (%r)", e)
        text = "Run `rigidjax --help` to list the options."
    return markdown.replace(MARKER, text)
