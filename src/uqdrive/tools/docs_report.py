"""`python -m uqdrive.tools.docs_report REPORT OUT` (`make docs-report`): the committed run's report for docs/, its
embedded figures re-encoded with 256-colour palettes, so the page stays self-contained under 2 MB (the run's own
report.html, 4.6 MB, holds 28 full-colour PNGs; the figures are flat-coloured plots, so a palette keeps them legible).
Nothing else of the page changes."""

from __future__ import annotations

import base64
import io
import re
import sys
from pathlib import Path

from PIL import Image

EMBEDDED_PNG = re.compile(r"data:image/png;base64,([A-Za-z0-9+/=]+)")


def palette_png(encoded: str) -> str:
    """One embedded PNG (base64) as a 256-colour palette PNG (base64)."""
    image = Image.open(io.BytesIO(base64.b64decode(encoded))).convert("RGB")
    out = io.BytesIO()
    image.quantize(256, method=Image.Quantize.MEDIANCUT).save(out, "PNG", optimize=True)
    return base64.b64encode(out.getvalue()).decode()


def shrink(html: str) -> str:
    return EMBEDDED_PNG.sub(lambda m: "data:image/png;base64," + palette_png(m.group(1)), html)


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python -m uqdrive.tools.docs_report REPORT OUT", file=sys.stderr)
        return 2
    Path(argv[1]).write_text(shrink(Path(argv[0]).read_text(encoding="utf8")), encoding="utf8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
