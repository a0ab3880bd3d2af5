"""`dvc plots show`'s page as a person sees it: rendered in headless Chromium (Debian's package), each plot read back.

A script put into the page before its plots wraps `vegaEmbed`: every Vega view renders as SVG, and once all are
drawn it walks each view's scenegraph, counting the data marks that take up room and collecting the axis titles,
checks that every image loaded, and writes what it found into the page as JSON; `chromium --dump-dom` prints the
page, and `render` reads that JSON back. No DevTools protocol, no driver: one Chromium process, bounded in time.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

WINDOW = "1280,900"  # a laptop's browser window: the room a page's images have
# Debian's Chromium on a machine whose only network is the package registries: no background connections, no sandbox
# (tests run as root), a fresh profile per run (https://www.chromium.org/developers/how-tos/run-chromium-with-flags/)
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--allow-file-access-from-files",
    f"--window-size={WINDOW}",
)
AXIS_TITLE_CHARS = 80  # an axis title a person reads at a glance: one line, no longer than this
INSTALL_HINT = "no Chromium: `make chromium` installs Debian's package (apt-get install chromium), as .ci/run does"

READ_BACK = """
<script>
(function () {
  const embed = window.vegaEmbed;
  const pending = [];
  const errors = [];
  window.addEventListener("error", (event) => errors.push(String(event.message)));
  function takesRoom(item) {
    const b = item.bounds;
    return Boolean(b) && Number.isFinite(b.x1) && Number.isFinite(b.y1) && b.x2 > b.x1 && b.y2 > b.y1;
  }
  function read(mark, drawn) {
    for (const item of mark.items || []) {
      if (mark.role === "mark" && mark.marktype !== "group") {
        drawn.items += 1;
        drawn.marks += takesRoom(item) ? 1 : 0;
      }
      if (mark.role === "axis-title" && item.text) drawn.axis_titles.push(String(item.text));
      for (const child of item.items || []) read(child, drawn);
    }
  }
  window.vegaEmbed = function (element, spec, options) {
    const drawn = {plot: String(element).replace(/^#/, ""), kind: "vega", items: 0, marks: 0, axis_titles: []};
    const embedded = embed(element, spec, Object.assign({}, options, {renderer: "svg", actions: false}));
    pending.push(
      embedded.then((result) => read(result.view.scenegraph().root, drawn))
        .catch((error) => { drawn.error = String(error); })
        .then(() => drawn)
    );
    return embedded;
  };
  window.addEventListener("load", () => {
    Promise.all(pending).then((views) => {
      const images = Array.from(document.querySelectorAll("img")).map((img) => {
        const panel = img.closest("div[id]");
        return {
          plot: panel ? panel.id : img.getAttribute("src"),
          kind: "image",
          items: 1,
          marks: img.complete && img.naturalWidth > 0 ? 1 : 0,
          axis_titles: [],
          width: Math.round(img.getBoundingClientRect().width),
          room: panel ? panel.clientWidth : null,
        };
      });
      const out = document.createElement("pre");
      out.id = "uqdrive-drawn";
      out.textContent = JSON.stringify({drawn: views.concat(images), errors: errors});
      document.body.appendChild(out);
    });
  });
})();
</script>
"""
DRAWN = re.compile(r'<pre id="uqdrive-drawn">(.*?)</pre>', re.S)


@dataclass(frozen=True)
class Drawn:
    """One plot of the page as rendered: ``marks``: data mark items that take up room (for an image: 1 if it
    loaded); ``items``: all data mark items; ``axis_titles``: every axis title the view shows; for an image, the
    ``width`` it is drawn at and the ``room`` its plot's panel has (CSS pixels)."""

    plot: str
    kind: str
    items: int
    marks: int
    axis_titles: tuple[str, ...]
    error: str | None = None
    width: int | None = None
    room: int | None = None


def chromium() -> str | None:
    """Debian's Chromium, if installed."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


def render(page: Path, timeout_s: float = 240) -> list[Drawn]:
    """Every plot of ``page`` (a `dvc plots show` index.html) as Chromium drew it; the page's script errors raise."""
    browser = chromium()
    if browser is None:
        raise FileNotFoundError(INSTALL_HINT)
    head, end, body = page.read_text(encoding="utf8").rpartition("</head>")  # the last: the inlined Vega has some
    if not end:
        raise ValueError(f"{page}: no </head> to put the read-back script before")
    checked = page.with_name(f"{page.stem}.read_back.html")  # beside the page: its images' relative paths hold
    checked.write_text(head + READ_BACK + end + body, encoding="utf8")
    with tempfile.TemporaryDirectory() as profile:
        dom = subprocess.run(
            [browser, *FLAGS, f"--user-data-dir={profile}", "--virtual-time-budget=60000", "--dump-dom"]
            + [checked.resolve().as_uri()],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env={**os.environ, "HOME": profile},
        )
    found = DRAWN.search(dom.stdout)
    if found is None:
        raise RuntimeError(f"Chromium drew no read-back (exit {dom.returncode}): {dom.stderr[-2000:]}")
    result = json.loads(_unescape(found.group(1)))
    if result["errors"]:
        raise RuntimeError(f"{page}: script errors: {result['errors']}")
    return [
        Drawn(
            d["plot"],
            d["kind"],
            d["items"],
            d["marks"],
            tuple(d["axis_titles"]),
            d.get("error"),
            d.get("width"),
            d.get("room"),
        )
        for d in result["drawn"]
    ]


def _unescape(text: str) -> str:
    return text.replace("&lt;", "<").replace("&gt;", ">").replace("&quot;", '"').replace("&amp;", "&")


def problems(drawn: list[Drawn]) -> list[str]:
    """What a person could not read: a view that failed, drew no data, has an untitled axis or an axis title that
    is not one short line; an image that did not load or is wider than its panel (cut off or scrolled)."""
    found = []
    for d in drawn:
        unreadable = [t for t in d.axis_titles if len(t) > AXIS_TITLE_CHARS or "\n" in t]
        if d.error:
            found.append(f"{d.plot}: {d.error}")
        elif d.kind == "image" and not d.marks:
            found.append(f"{d.plot}: image did not load")
        elif d.kind == "image" and d.room is not None and d.width > d.room:
            found.append(f"{d.plot}: image {d.width} px wide in a panel of {d.room} px")
        elif d.kind == "vega" and not d.marks:
            found.append(f"{d.plot}: no data marks ({d.items} drawn with no extent)")
        elif d.kind == "vega" and (len(set(d.axis_titles)) < 2 or any("DVC_METRIC" in t for t in d.axis_titles)):
            found.append(f"{d.plot}: axes without titles {list(d.axis_titles)}")
        elif unreadable:
            found.append(f"{d.plot}: axis titles longer than {AXIS_TITLE_CHARS} characters or a line {unreadable}")
    return found
