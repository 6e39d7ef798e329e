"""TTOBench (Kouzoupis, Pendharkar, Corman, OR Forum 4:67, 2023) tracks, trains and journeys.

:mod:`metro_atc.ttobench.importer` maps the JSON formats onto a metro_atc scenario (mapping in
``README.md`` next to this file); the vendored metro instance is in ``metro_atc/data/ttobench``.
"""
