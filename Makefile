# The README's two commands. Each one sets up whatever is missing first.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: lerobot-deps lerobot-test wheel run test checks test-slow-machine test-web screenshots lint typecheck unit unit-no-browser unit-browser browser-deps turn-deps media-server-deps slow-machine-deps web web-check bench clean types

WEB_SOURCES := $(shell find web/src -type f 2>/dev/null) web/index.html web/calibration.html web/review.html web/vite.config.ts web/tsconfig.json

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

web/node_modules/.installed: web/package.json web/package-lock.json
	cd web && npm install --no-audit --no-fund --loglevel=error  # (npm ci trips over optional native bindings)
	@touch $@

backend/web/index.html: web/node_modules/.installed $(WEB_SOURCES)
	cd web && npm run --silent build

## make wheel: the package, with its page, as dist/telerobot-*.whl (docs/running.md)
wheel: $(STAMP) web
	rm -rf build dist
	$(BIN)/python -m pip wheel --no-deps --no-build-isolation --wheel-dir dist .

## make web: build the operator client (TypeScript + three.js) into backend/web
web: backend/web/index.html

## make run: start the server on the simulation and print its URL
run: $(STAMP) web
	$(BIN)/telerobot serve $(ARGS)

## make test: install what is missing, then lint, type-check and run every test (browser
## and LeRobot's tools included), one part after the other: the checks (lint, mypy, the
## page's lint, types and vitest), the tests that need no browser, LeRobot's, the
## browser's. LEROBOT_BESIDE=yes (or auto: when 1.5 cores are idle at the start) runs the
## checks and LeRobot's tests beside the tests that need no browser, their output shown
## when both are done. Not by default: on a 2-core Intel Xeon it saved 29 s of 641 and
## four timing-bound tests failed under the load (docs/PERFORMANCE.md, machine B).
LEROBOT_BESIDE ?= no
test: $(STAMP) browser-deps turn-deps media-server-deps lerobot-deps web
	@beside='$(LEROBOT_BESIDE)'; \
	  if [ "$$beside" = auto ]; then \
	    idle=$$(tools/idle-cores); \
	    beside=$$(awk -v i="$$idle" 'BEGIN { print (i >= 1.5 ? "yes" : "no") }'); \
	    echo "$$idle cores idle: the checks and LeRobot's tests run $$( [ $$beside = yes ] && echo beside the others || echo before and after them)"; \
	  fi; \
	  if [ "$$beside" != yes ]; then \
	    $(MAKE) --no-print-directory checks unit-no-browser lerobot-test; exit $$?; \
	  fi; \
	  log=$$(mktemp -t telerobot-beside.XXXXXX); \
	  echo "The checks and LeRobot's tests run beside the tests that need no browser; their output follows those"; \
	  $(MAKE) --no-print-directory checks lerobot-test >$$log 2>&1 & beside=$$!; \
	  $(MAKE) --no-print-directory unit-no-browser; own=$$?; \
	  wait $$beside; theirs=$$?; \
	  echo "--- the checks and LeRobot's tests (make checks lerobot-test):"; cat $$log; rm -f $$log; \
	  test $$own = 0 && test $$theirs = 0
	@$(MAKE) --no-print-directory unit-browser

## make checks: lint, type-check, and the page's lint, types and unit tests (vitest)
checks: lint typecheck web-check

# LeRobot needs Python 3.12 and brings torch (~5.4 GB): a venv of its own, installed once
# and kept between runs and clones (the plugins' tests and LeRobot's reading of our
# exports run in it; docs/lerobot.md).
LEROBOT_VERSION := 0.6.1
LEROBOT_VENV ?= $(HOME)/.cache/telerobot/lerobot-$(LEROBOT_VERSION)
LEROBOT_PY := $(LEROBOT_VENV)/bin/python
# The interpreter is found by tools/find-python312, which runs each candidate: pyenv's
# `python3.12` shim is on PATH but refuses while 3.12 is not a selected version.
# PYTHON312=/path/to/python3.12 picks one by hand.

# torchcodec (LeRobot's video decoder) loads FFmpeg's shared libraries (4 to 8): Debian
# 12's are FFmpeg 5.1's; without them LeRobot prints a long traceback at every start.
FFMPEG_LIBS := libavutil57 libavcodec59 libavformat59 libavdevice59 libavfilter8 libswscale6 libswresample4
# [feetech]: LeRobot's own SO-101 leader, on Telerobot's emulated servo bus, in the tests.
# Telerobot's client comes from this checkout's path, not installed, so what it imports
# is listed here (pydantic for its tokens, websockets for the tests' realtime client): a
# fresh machine's venv had neither, and LeRobot's tests stopped at their first import.
LEROBOT_SPEC := lerobot[dataset,feetech]==$(LEROBOT_VERSION) pytest pytest-timeout httpx aiortc setuptools pydantic>=2.6 websockets
# Checked on every run (cheap): the stamp holds the spec and the interpreter it was made
# with, so a changed spec or a venv whose Python no longer runs installs again.
lerobot-deps:
	@LEROBOT_VENV='$(LEROBOT_VENV)' LEROBOT_SPEC='$(LEROBOT_SPEC)' PYTHON312='$(PYTHON312)' tools/lerobot-venv
	@ldconfig -p | grep -q 'libavdevice\.so\.59 ' || { \
	  echo "installing Debian's FFmpeg libraries for LeRobot's video decoder (torchcodec)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(FFMPEG_LIBS) >/dev/null \
	  || { echo "as root: apt-get install $(FFMPEG_LIBS)"; exit 1; }; }

## make lerobot-test: the LeRobot plugins in LeRobot's own command lines, against a real server
# The plugins are installed anew from this checkout each time (LeRobot finds plugins by
# their installed distributions); Telerobot's client comes from this checkout's path.
lerobot-test: $(STAMP) lerobot-deps
	$(LEROBOT_PY) -m pip install --quiet --no-deps --no-build-isolation --force-reinstall \
	  ./integrations/lerobot/robot ./integrations/lerobot/teleoperator
	cd integrations/lerobot && PYTHONPATH=$(CURDIR) TELEROBOT_SERVE=$(CURDIR)/$(BIN)/telerobot \
	  $(LEROBOT_PY) -m pytest -q

## make test-slow-machine: the whole of `make test` with one of the cores kept busy
## (Debian's stress-ng): the suite is meant to pass under it, every time
test-slow-machine: slow-machine-deps
	@stress-ng --cpu 1 --timeout 3600 --quiet & STRESS=$$!; \
	  trap 'kill $$STRESS 2>/dev/null' EXIT; \
	  $(MAKE) test

slow-machine-deps:
	@command -v stress-ng >/dev/null 2>&1 || { \
	  echo "installing Debian's stress-ng to keep a core busy"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq stress-ng >/dev/null; }

## make test-web: only the browser tests (the operator page with live video, the status page)
test-web: $(STAMP) browser-deps web
	$(BIN)/python -m pytest -q -m browser

## make screenshots: the operator page's views, saved into docs/img for the README
screenshots: $(STAMP) browser-deps web
	TELEROBOT_SCREENSHOTS=docs/img $(BIN)/python -m pytest -q tests/test_web.py -k screenshots

## make types: regenerate the web client's types from the server (binary messages, REST schema)
types: $(STAMP) web/node_modules/.installed
	$(BIN)/python -m telerobot.server.realtime.typescript > web/src/transport/messages.ts
	$(BIN)/python -m telerobot.server.api.openapi_ts

web-check: web/node_modules/.installed
	cd web && npm run --silent lint && npm run --silent typecheck && npm run --silent test

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

# Two runs: the tests that need no browser on three workers (their servers, emulators
# and sockets mostly wait: 286 s on two → 233 s on three here, 1.2 cores used), then the
# browser tests on one, which share one Chromium and take the CPU the page's software
# rendering needs (two workers are no faster: 389 s against 378; docs/PERFORMANCE.md).
# With LEROBOT_BESIDE=yes (or auto and 1.5 cores idle: tools/idle-cores) `make test`
# runs LeRobot's tests beside the first: on machine A quiet, 384 s for both against
# 382 + 138; on machine B 612 + 370 s against 465 + 176 one after the other, with four
# timing-bound failures; with a core busy they slowed each other (594 s for the first).
unit: unit-no-browser unit-browser

unit-no-browser: $(STAMP)
	TELEROBOT_LEROBOT_PYTHON=$$(test -x $(LEROBOT_PY) && echo $(LEROBOT_PY)) \
	  $(BIN)/python -m pytest -q -m "not browser" -n 3 --dist loadfile

unit-browser: $(STAMP)
	$(BIN)/python -m pytest -q -m browser

# Debian's Chromium for the Playwright browser tests (never a downloaded browser).
browser-deps:
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing Debian's chromium for the browser tests"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; }

# Debian's coturn for the TURN relay tests (tests/support/coturn.py starts its own turnserver;
# the package's system service stays off).
turn-deps:
	@command -v turnserver >/dev/null 2>&1 || { \
	  echo "installing Debian's coturn for the TURN tests"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq coturn >/dev/null; }

# Debian's Janus for the media-server tests (backend/media/janus.py starts its own, with
# a generated configuration; the package's system service stays off).
media-server-deps:
	@command -v janus >/dev/null 2>&1 || { \
	  echo "installing Debian's janus for the media-server tests"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends janus >/dev/null; }

bench: $(STAMP)
	$(BIN)/python -m bench.kinematics

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache backend/web build dist
