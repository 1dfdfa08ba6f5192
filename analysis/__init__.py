"""Command-line studies: ``python -m analysis.<name>``."""
