"""report.html: the run's report as one self-contained page beside report.md, with the web player embedded.

Owns: :func:`write_report_html` (the run folder's ``web/`` player and ``report.html``) and :func:`render_html`.
The page renders the very blocks ``report.report_blocks`` gives report.md (tables, the plot, the side-by-side
views and crops), links images by their paths relative to the run folder, and embeds
``web/index.html?camera=0&fit`` (the bundle exported by ``export/web.py``) in an iframe with the aspect of held-out
camera 0, at least ``MIN_PLAYER_WIDTH`` wide. Nothing is fetched from outside the folder; it works opened from
``file://`` (the player then reads ``web/data.js``) and served by ``python -m http.server`` (the player fetches
its files).
"""

from __future__ import annotations

import html
import json
import re
import shutil
from pathlib import Path

from .report import report_blocks

WEB_DIR = "web"
PLAYER_SRC = f"{WEB_DIR}/index.html?camera=0&fit"
MIN_PLAYER_WIDTH = 640          # px on the page: a small camera's frame is shown magnified

_STYLE = """
body { font: 14px/1.45 sans-serif; margin: 0 auto; max-width: 1280px; padding: 0 16px 32px; color: #222; }
h1 { font-size: 24px; } h2 { font-size: 18px; margin-top: 28px; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 8px 0; }
th, td { border: 1px solid #ccc; padding: 3px 10px; text-align: left; }
th { background: #f2f2f2; }
figure { margin: 10px 0; } figure img { max-width: 100%; image-rendering: pixelated; }
figcaption { color: #555; }
li img { display: block; max-width: 100%; margin: 4px 0 10px; image-rendering: pixelated; }
iframe.player { border: 0; outline: 1px solid #ccc; width: 100%; display: block; }
.note { color: #555; }
"""


def _inline(text: str) -> str:
    """Escaped ``text`` with its **bold** spans as <strong>."""
    return re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", html.escape(text))


def _figure(fig, tag: str = "figure") -> str:
    src, alt, caption = fig
    img = f'<img src="{html.escape(src)}" alt="{html.escape(alt)}">'
    if tag != "figure":
        return img
    return f"<figure>{img}" + (f"<figcaption>{html.escape(caption)}</figcaption>" if caption else "") + "</figure>"


def _table(header, rows) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def block_html(block) -> str:
    kind = block[0]
    if kind == "heading":
        return f"<h{block[1]}>{html.escape(block[2])}</h{block[1]}>"
    if kind == "para":
        return f"<p>{_inline(block[1])}</p>"
    if kind == "table":
        return _table(block[1], block[2])
    if kind == "list":
        items = "".join(f"<li>{_inline(text)}" + (_figure(fig, "img") if fig else "") + "</li>"
                        for text, fig in block[1])
        return f"<ul>{items}</ul>"
    if kind == "figures":
        return "".join(_figure(fig) for fig in block[1])
    raise ValueError(f"unknown report block {kind!r}")


def _player_html(size: tuple[int, int] | None, reason: str | None = None) -> str:
    """The section embedding the web player (or saying why there is none: ``reason``, else no bundle)."""
    if size is None:
        why = html.escape(reason) if reason else f"no bundle was exported to {WEB_DIR}/"
        return f'<h2>Play the bundle</h2><p class="note">No web player in this run folder ({why}).</p>'
    w, h = size
    return ("<h2>Play the bundle</h2>"
            f'<iframe class="player" src="{html.escape(PLAYER_SRC)}" title="neuras-distill web player" '
            f'style="max-width: {max(w, MIN_PLAYER_WIDTH)}px; aspect-ratio: {w} / {h};"></iframe>'
            '<p class="note">WebGL2, held-out camera 0 at its own resolution: drag to orbit, wheel to zoom. '
            f'Full page: <a href="{WEB_DIR}/index.html">{WEB_DIR}/index.html</a> (<code>?camera=N</code> plays '
            "held-out camera N).</p>")


def _other_views(root: Path, shown: set[str]) -> str:
    """Images under views/ that no block shows (e.g. the lane shifts' views/lane_*.png)."""
    rest = sorted(p.relative_to(root).as_posix() for p in (root / "views").glob("*.png")) \
        if (root / "views").is_dir() else []
    rest = [p for p in rest if p not in shown]
    if not rest:
        return ""
    return "<h2>Other views (field | bundle | error x10)</h2>" + "".join(
        _figure((p, Path(p).stem, Path(p).stem)) for p in rest)


def _shown_images(blocks) -> set[str]:
    out = set()
    for block in blocks:
        if block[0] == "figures":
            out |= {fig[0] for fig in block[1]}
        elif block[0] == "list":
            out |= {fig[0] for _, fig in block[1] if fig}
    return out


def render_html(rep: dict, root: Path, player_size: tuple[int, int] | None, no_player: str | None = None) -> str:
    """The page for report ``rep`` of the run folder ``root``; ``player_size`` (w, h) of the embedded player's
    camera, or None without a player (``no_player``: why, shown on the page). The player follows the summary
    table (the report's first table)."""
    blocks = report_blocks(rep)
    parts = []
    first_table = next(i for i, b in enumerate(blocks) if b[0] == "table")
    for i, block in enumerate(blocks):
        parts.append(block_html(block))
        if i == first_table:
            parts.append(_player_html(player_size, no_player))
    parts.append(_other_views(root, _shown_images(blocks)))
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            "<title>neuras-distill report</title>\n<style>" + _STYLE + "</style>\n</head>\n<body>\n"
            + "\n".join(p for p in parts if p) + "\n</body>\n</html>\n")


def _camera_size(web: Path) -> tuple[int, int]:
    test = json.loads((web / "cameras.json").read_text("utf-8"))["test"]
    return int(test["w"]), int(test["h"])


def write_report_html(root: Path, rep: dict) -> Path:
    """Export ``root/bundle`` (when there is one) as the web player ``root/web`` and write ``root/report.html``.
    Returns the page's path. A bundle the web export refuses (a texture above its limit, ``export/texture_limit.py``)
    gets the page without a player, saying why."""
    from ..errors import BadInputError
    from ..export.web import MARKER, export_web

    root = Path(root)
    size, reason = None, None
    if (root / "bundle").is_dir():
        try:
            web = export_web(root / "bundle", root / WEB_DIR)
        except BadInputError as exc:
            reason = f"the web export refused the bundle: {exc}"
            if (root / WEB_DIR / MARKER).is_file():       # a player of an earlier bundle would mislead
                shutil.rmtree(root / WEB_DIR)
        else:
            size = _camera_size(web)
    path = root / "report.html"
    path.write_text(render_html(rep, root, size, reason), encoding="utf-8")
    return path


__all__ = ["PLAYER_SRC", "WEB_DIR", "render_html", "write_report_html"]
