"""``python -m metro_atc`` entry point."""

from metro_atc.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
