"""`uqdrive plots-page`: the page `dvc plots show` fills, with Vega, Vega-Lite and Vega-Embed inlined.

DVC's own page loads those libraries from a CDN, so on a machine without internet access (ours reach only the
package registries) every CSV plot stays blank. The page written here carries them (vl-convert's bundle, about
0.9 MB); `make install` writes it and names it in the checkout's own `.dvc/config.local` (`plots.html_template`),
so `dvc plots show` draws offline there, and a checkout without it (a fresh clone) gets DVC's own page, not an
error about a template that is not there. A figure wider than the window is shrunk to its panel, not cut off (DVC's
panels hide what overflows).
"""

from __future__ import annotations

import argparse
from pathlib import Path

VEGA_LITE = "v5.20"  # DVC's plot templates are Vega-Lite 5 specs
PAGE = """<!DOCTYPE html>
<html>
<head>
    {{refresh_tag}}
    <title>DVC Plot</title>
    <script type="text/javascript">
{bundle}
    </script>
    <style>
        table {{
            border-spacing: 15px;
        }}
        img {{
            max-width: 100%;
            height: auto;
        }}
    </style>
</head>
<body>
    {{plot_divs}}
</body>
</html>
"""


def write_page(path: Path) -> Path:
    import vl_convert

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(PAGE.format(bundle=vl_convert.javascript_bundle(vl_version=VEGA_LITE)), encoding="utf8")
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="uqdrive plots-page", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(".dvc/plots_page.html"), help="where to write the page")
    args = parser.parse_args(argv)
    print(f"wrote {write_page(args.out)}")
    return 0
