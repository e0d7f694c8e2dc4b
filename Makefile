# egovid — two commands on a fresh machine:  make demo   and   make test
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
# System packages: ffmpeg (the vid.stab peer of the stabiliser's tests and benchmark; it also brings
# Debian's libvpx, a second VP9 build the dashcam codec can use via EGOVID_LIBVPX) and postgresql
# (the server binaries: the tests start a throw-away server for the dashcam's PostgreSQL catalogue),
# libimage-exiftool-perl (camera metadata and embedded GPS through pyexiftool) and chromium (the
# headless browser that checks the archive's HTML map); postgresql-postgis (the tests check the
# catalogue's PostGIS spatial index as well as the plain GiST one).
APT_PACKAGES := ffmpeg postgresql libimage-exiftool-perl chromium postgresql-postgis

.PHONY: help install sysdeps demo test lint bench clean

help:
	@echo "make demo   create .venv, install egovid and run the main jobs end to end on generated data"
	@echo "make test   install and run the linter and the test suite"
	@echo "make bench  run the benchmarks in benchmarks/ (minutes)"

sysdeps:
	@missing=""; \
	command -v ffmpeg >/dev/null || missing="$$missing ffmpeg"; \
	{ command -v initdb || ls /usr/lib/postgresql/*/bin/initdb; } >/dev/null 2>&1 || missing="$$missing postgresql"; \
	command -v exiftool >/dev/null || missing="$$missing libimage-exiftool-perl"; \
	command -v chromium >/dev/null || missing="$$missing chromium"; \
	ls /usr/share/postgresql/*/extension/postgis.control >/dev/null 2>&1 || missing="$$missing postgresql-postgis"; \
	if [ -n "$$missing" ]; then \
	  echo "installing system packages:$$missing"; \
	  SUDO=$$([ "$$(id -u)" -eq 0 ] || echo sudo); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $$missing; \
	fi

$(STAMP): pyproject.toml
	@$(MAKE) --no-print-directory sysdeps
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[dev]'
	@touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/egovid demo --out demo-output

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks experiments

# Two pytest workers, a test file each (--dist loadfile keeps a file's shared fixtures in one
# process): one worker often waits on a subprocess, a server or the encoder while the other
# computes. 798 tests: 8.7 min of pytest, 9.4 min for make test from a clean clone with ../shared
# beside it (2026-12-05, the 2-core machine at load 10-12; 8.0 min for 749 tests when quiet on
# 2026-12-04, 17.7 min with others' benchmarks at load 20-27). 833 tests: 21.9 min of pytest from a
# clean clone with ../shared at load 4-5 (2026-12-07), after SVT-AV1's real-time priority was kept
# out of the test workers (voeval's grid test 515 s -> 43 s, the EIS test 278 s -> 30 s). 839 tests:
# 19.0 min of pytest, 20.7 min for make test from a clean clone with ../shared at load 3.5-4.6
# (2026-12-08), after the stabiliser's interrupt tests moved to their own file on a short job.
# 842 tests: 13.8 min of pytest, 15.5 min for make test (clean clone with ../shared, alone, load
# 0.8-4.3, 2026-12-08 03:14-03:30), after the real-clip motion runs were shared within one module
# and the refusal and read-only commands ran in process.
# --durations names the slowest, so a CI log says where the time went. The whole run is
# interrupted after 70 minutes (pytest then prints what it has, stacks and summary) so that a hang
# shows in the log instead of running into CI's 90-minute limit with nothing printed.
test: $(STAMP)
	$(BIN)/ruff check src tests benchmarks experiments
	timeout -s INT -k 120 70m $(BIN)/pytest -q -n 2 --dist loadfile --durations=25

bench: $(STAMP)
	$(BIN)/pip install -q -e '.[dev,bench]'
	@for b in benchmarks/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) demo-output .pytest_cache build src/*.egg-info
