# metro_atc — the two commands:
#   make demo   set up (idempotent), build, run the default scenario through the ROS graph
#   make test   set up (idempotent), build, run the whole test suite (unit, integration, lint)
SHELL := /bin/bash
SCENARIO ?= taipei_blue
REGULATOR ?= none
PYTEST_ARGS ?=

.PHONY: setup demo test clean

setup:
	@bash scripts/install.sh

demo: setup
	@source env.sh && python -m metro_atc run --scenario $(SCENARIO) --regulator $(REGULATOR) --out out/demo --progress always

test: setup
	@source env.sh && python -m pytest test -q $(PYTEST_ARGS)

clean:
	rm -rf build install log out log_*.txt
