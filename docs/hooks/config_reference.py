"""MkDocs hook: replaces the marker ``<!-- config-reference -->`` in a page with the table of
the environment's configuration keys, rendered from their one source
(:func:`envs.config.config_reference`)."""

MARKER = "<!-- config-reference -->"


def on_page_markdown(markdown, page, config, files):
    if MARKER not in markdown:
        return markdown
    from envs.config import config_reference

    return markdown.replace(MARKER, config_reference())
