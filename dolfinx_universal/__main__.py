"""Entry point of ``python -m dolfinx_universal`` (see :mod:`dolfinx_universal.cli`)."""

from dolfinx_universal.cli import main

__all__: list[str] = []

if __name__ == "__main__":
    raise SystemExit(main())
