"""The repository's root, for tests that read its files (docs, README, benchmarks, data)."""

from pathlib import Path

#: The repository checkout the tests run from (the folder holding ``pyproject.toml``).
ROOT = Path(__file__).resolve().parent.parent
