"""uqdrive: Bayesian end-to-end driving controllers with statistically guaranteed safety."""

__version__ = "0.1.0"

INPUT_HEIGHT, INPUT_WIDTH = 48, 64
"""The frame the networks see (grey, 64x48, the paper's): the camera delivers it, the data pipeline stores it."""
