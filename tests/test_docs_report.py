"""docs/report.html is the run's report with its embedded figures on 256-colour palettes: smaller, the same picture
size, the rest of the page untouched."""

import base64
import io

import numpy as np
from PIL import Image

from uqdrive.tools.docs_report import shrink


def test_embedded_pngs_become_palette_pngs_of_the_same_size_and_the_text_stays():
    pixels = np.random.default_rng(0).integers(0, 255, (60, 80, 3), dtype=np.uint8)
    raw = io.BytesIO()
    Image.fromarray(pixels).save(raw, "PNG")
    html = f'<p>η1 0.93</p><img src="data:image/png;base64,{base64.b64encode(raw.getvalue()).decode()}">'
    small = shrink(html)
    assert small.startswith('<p>η1 0.93</p><img src="data:image/png;base64,')
    image = Image.open(io.BytesIO(base64.b64decode(small.split("base64,")[1].rstrip('">'))))
    assert image.mode == "P" and image.size == (80, 60)
