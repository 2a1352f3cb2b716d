"""The version of airpuff, written into every result file (its own module, so that the core's
modules can read it without importing the package)."""

__version__ = "0.1.0"
