"""Reproductions and benchmarks: ``python -m metro_atc bench NAME`` (see metro_atc.cli)."""
