# The two commands a user needs: `make demo` and `make test`. Both create .venv and install.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# test processes (pytest-xdist): the suite is mostly single-threaded Python and subprocesses, so
# two use both cores of the 2-core machines it must pass on (`make test TEST_WORKERS=1`: one);
# the 15 longest tests are listed at the end (docs/testing.md, *Keeping it*)
TEST_WORKERS ?= 2
PYTEST := $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist worksteal --durations=15

.PHONY: demo test test-all lint typecheck bench clean venv browser venv-peers

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

# The learner's kernels compile (`roger compile`, below: ~90 s of CPU) while pip installs the
# rest on one core: the few packages their modules import go in first, with pyproject.toml's
# constraints (KERNEL_DEPS), then `python -m roger_daemon compile` runs from the source tree
# beside the main install (docs/testing.md, *Budget*). If it fails, the `roger compile` of
# `make test` and `make demo` compiles instead (its log: .venv/compile.log).
KERNEL_DEPS := numpy numba scipy msgpack threadpoolctl
$(STAMP): pyproject.toml
	@echo "==> creating $(VENV) and installing roger with its dependencies (about 1.5 min the first time)"
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet $$($(BIN)/python -c "import tomllib; \
	  deps = tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']; \
	  print(' '.join(d for d in deps if d.split('>')[0].split('=')[0] in '$(KERNEL_DEPS)'.split()))")
	$(BIN)/python -m roger_daemon compile >$(VENV)/compile.log 2>&1 & compiling=$$!; \
	  $(BIN)/python -m pip install --progress-bar on -e '.[test]'; installed=$$?; \
	  wait $$compiling || echo "==> the kernels were not compiled yet (.venv/compile.log)"; \
	  test $$installed -eq 0
	touch $(STAMP)
	@echo "==> installed: run commands as $(BIN)/roger, or '. $(BIN)/activate' first"

# `roger compile` fills numba's cache of the learner's kernels on every core (about 35 s on a
# 2-core machine the first time, 2 s after): every later process loads them instead of
# compiling them itself (about a minute each). The demo runs even if it fails (`-`: numba
# without a writable cache directory; the demo's processes then compile for themselves).
demo: $(STAMP)
	-$(BIN)/roger compile
	$(BIN)/roger demo

# the browser's install (network and disk, when chromium is missing) runs beside ruff and
# `roger compile` (CPU; a few seconds once `make venv` compiled the kernels), and pytest
# starts once they are done; mypy (~30 s from a fresh clone, one core) runs beside all of
# them and the first tests, its report printed after pytest's (docs/testing.md, *Budget*)
test: $(STAMP)
	$(MAKE) --no-print-directory browser & browser=$$!; \
	  $(BIN)/mypy >$(VENV)/mypy.out 2>&1 & typing=$$!; \
	  $(BIN)/ruff check . && linted=0 || linted=1; \
	  $(BIN)/roger compile; compiled=$$?; wait $$browser; \
	  if test $$linted -eq 0 && test $$compiled -eq 0; then $(PYTEST); tested=$$?; \
	  else tested=1; fi; \
	  wait $$typing; typed=$$?; echo "==> mypy"; cat $(VENV)/mypy.out; \
	  test $$linted -eq 0 && test $$typed -eq 0 && test $$compiled -eq 0 && test $$tested -eq 0

test-all: $(STAMP) browser
	$(BIN)/roger compile
	$(PYTEST) -m ''

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/roger bench learner

# `roger experiment peers` (docs/peers.md): LeRobot's ACT and Diffusion Policy in their own venv.
# LeRobot 0.4.4 (the last release for Python 3.11) needs torch >= 2.2.1, < 2.11 and torchvision;
# torch 2.9.1 with torchvision 0.24.1 go in first (about 7 GB: PyPI's torch is a CUDA build, run
# on the CPU here), then roger with the peers and test extras.
PEERS_VENV := .venv-peers
venv-peers: $(PEERS_VENV)/.installed

$(PEERS_VENV)/.installed: pyproject.toml
	test -x $(PEERS_VENV)/bin/python || $(PY) -m venv $(PEERS_VENV)
	$(PEERS_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(PEERS_VENV)/bin/python -m pip install torch==2.9.1 torchvision==0.24.1
	$(PEERS_VENV)/bin/python -m pip install -e '.[peers,test]'
	touch $@

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
