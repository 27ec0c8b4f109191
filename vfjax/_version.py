"""vfjax's version: one definition, read by the package, its command line, the records a
cohort keeps and the build (``pyproject.toml``)."""

__version__ = "0.1.0"
