# The two commands a newcomer needs (see README.md):
#   make serve   install everything, then start the service on http://127.0.0.1:8000 (UI at /docs)
#   make test    install everything, then run every check and test (what CI runs)

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV ?= .venv
BIN := $(VENV)/bin
INSTALLED := $(VENV)/.installed

.PHONY: install browser postgres serve test lint clean

# Python writes bytecode here even where the environment says not to (some images set
# PYTHONDONTWRITEBYTECODE=1): the tests start hundreds of Python processes (servers, parser
# and export workers, command lines), and without it each compiled the application again
# (~0.4 s of CPU a process for `import app.main`) and every test worker rewrote every test
# module's assertions again.
unexport PYTHONDONTWRITEBYTECODE

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# Reinstall whenever the dependencies change. The `fbx` extra (bpy, ~1 GB: Blender's FBX
# exporter for format=fbx) may fail where no wheel exists for this platform: then everything
# else is installed, format=fbx answers 501 (fbx_unavailable) and the FBX tests skip, except
# in CI. One pip run: two resolved and installed everything twice. pip compiles nothing
# (one file at a time: ~40 s of the install); Blender's own scripts are then compiled on
# every core, as they must be at install: Blender turns off writing bytecode, so without it
# every Blender worker compiled them again (`import bpy` 4.9 s instead of 1.2 s, the tests'
# first phase 13:04 instead of 10:43). Everything else is compiled by the first process that
# imports it (a small part of the 8,000 files installed: compiling all of them cost ~45 s of
# CPU, bpy's ~4 s).
PIP_INSTALL = $(BIN)/python -m pip install --quiet --no-compile
SITE_PACKAGES = $(BIN)/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])'
$(INSTALLED): pyproject.toml | $(BIN)/python
	$(PIP_INSTALL) -e '.[dev,fbx]' || $(PIP_INSTALL) -e '.[dev]'
	site="$$($(SITE_PACKAGES))"; [ ! -d "$$site/bpy" ] || \
		$(BIN)/python -m compileall -q -j 0 "$$site/bpy" > /dev/null
	touch $@

install: $(INSTALLED)

serve: install
	$(BIN)/mocap-index serve --host 127.0.0.1 --port 8000

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy app

# Debian's chromium for the web UI's browser tests (apt-get; needs root or sudo). Where it
# cannot be installed those tests skip with a reason, except in CI (MOCAP_REQUIRE_BROWSER=1).
browser: install
	-bash scripts/install_browser.sh $(BIN)/python

# Debian's PostgreSQL 15 for the tests on PostgreSQL (apt-get; needs root or sudo). Where it
# cannot be installed those tests skip with a reason, except in CI (CI=true).
postgres:
	-bash scripts/install_postgres.sh

# Two phases: most tests in TEST_WORKERS processes, a test file per process at a time
# (pytest-xdist; a crashed worker ends the run rather than being replaced); then the tests
# that time the service's answers (a /health within 1 s during each request, a change seen
# by another process within the refresh + 1 s) alone, so they do not share the cores with
# other tests. A new test that times the service belongs in TIMED_TESTS. Three processes on
# a two-core machine: a fifth of the time the tests wait on servers, browsers and
# subprocesses (measured here: 8:17 for the first phase against 9:38 with two). Files are
# handed out longest first (the order tests/conftest.py gives them; see there). The two
# replicas' test waits for what one sees of the other (bench/bench_visibility.py times it):
# it runs in the first phase.
TEST_WORKERS ?= 3
TIMED_TESTS = tests/hostile tests/hardening/test_upload_fuzz.py tests/hardening/test_busy.py \
	tests/hardening/test_access.py tests/hardening/test_load.py tests/hardening/test_workers.py

# The type check runs beside the first phase (a clean clone has no mypy cache: ~40 s of CPU
# that would otherwise wait before every test); its verdict and output come after it.
test: install browser postgres
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy app > $(VENV)/mypy.log 2>&1 & typecheck=$$!; \
	$(BIN)/pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder --max-worker-restart=0 \
		$(foreach t,$(TIMED_TESTS),--ignore=$(t)); tests=$$?; \
	wait $$typecheck; typed=$$?; cat $(VENV)/mypy.log; \
	[ $$tests -eq 0 ] && [ $$typed -eq 0 ]
	$(BIN)/pytest $(TIMED_TESTS)

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
