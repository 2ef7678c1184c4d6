# The two commands a user needs: `make demo` and `make test`. Both create .venv and install.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# test processes (pytest-xdist): the suite is mostly single-threaded Python and subprocesses, so
# two use both cores of the 2-core machines it must pass on (`make test TEST_WORKERS=1`: one)
TEST_WORKERS ?= 2
PYTEST := $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist worksteal

.PHONY: demo test test-all lint typecheck bench clean venv browser

venv: $(STAMP)

# roger teach's browser test drives Debian's chromium (tests/test_teach_browser.py): installed
# here when missing and this is root (CI is); nothing to do when it is there already
CHROMIUM ?= /usr/bin/chromium
browser:
	@test -x $(CHROMIUM) || { if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "==> installing chromium for the browser test (apt-get)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium \
	    >/dev/null; else echo "==> no $(CHROMIUM): the browser test is skipped (apt-get \
	install chromium)"; fi; }

$(STAMP): pyproject.toml
	@echo "==> creating $(VENV) and installing roger with its dependencies (about 1.5 min the first time)"
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --progress-bar on -e '.[test]'
	touch $(STAMP)
	@echo "==> installed: run commands as $(BIN)/roger, or '. $(BIN)/activate' first"

# `roger compile` fills numba's cache of the learner's kernels on every core (about 35 s on a
# 2-core machine the first time, 2 s after): every later process loads them instead of
# compiling them itself (about a minute each). The demo runs even if it fails (`-`: numba
# without a writable cache directory; the demo's processes then compile for themselves).
demo: $(STAMP)
	-$(BIN)/roger compile
	$(BIN)/roger demo

test: $(STAMP) browser
	$(BIN)/ruff check .
	$(BIN)/roger compile & compiling=$$!; $(BIN)/mypy; typed=$$?; wait $$compiling && test $$typed -eq 0
	$(PYTEST)

test-all: $(STAMP) browser
	$(BIN)/roger compile
	$(PYTEST) -m ''

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/roger bench learner

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
