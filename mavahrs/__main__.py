"""``python -m mavahrs`` — the same as the ``mavahrs`` command."""

from __future__ import annotations

from mavahrs.cli import console_main

if __name__ == "__main__":
    console_main()
