"""CMU-Drive: a closed-loop benchmark for cooperative (multi-CAV) autonomous driving."""

__version__ = "0.1.0"  # the package's version (pyproject.toml reads it from here)
