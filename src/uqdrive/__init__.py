"""uqdrive: Bayesian end-to-end driving controllers with statistically guaranteed safety."""

__version__ = "0.1.0"
