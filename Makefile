# Set-up and entry points of cellctl.  `make demo` and `make test` each do all
# set-up on a fresh Debian machine with Python 3.11: system packages, the
# virtual environment, the Python dependencies and the C core.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Compiler and headers for the C core; libgomp for its threads; libusb for Open3D; chromium and its
# driver for the operator station's browser tests; mbpoll (libmodbus) and socat for the Modbus
# conformance test (a master nobody here wrote, over TCP and an RTU pty pair).
APT_PACKAGES := python3-venv python3-dev gcc libc6-dev libgomp1 libusb-1.0-0 chromium chromium-driver mbpoll socat
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
SANITIZE := -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined

.PHONY: demo test quick check asan bench eval sysdeps clean

demo: $(STAMP)
	$(BIN)/cellctl demo

test: $(STAMP)
	$(BIN)/python -m pytest
	$(MAKE) check
	$(MAKE) asan

# The tests without those marked slow, for the edit-test loop (make test runs them all).
quick: $(STAMP)
	$(BIN)/python -m pytest -m "not slow"

# Lint, format, types and the import layers (configured in pyproject.toml).
check: $(STAMP)
	$(BIN)/ruff check cellctl firmware_io tests csrc
	$(BIN)/ruff format --check cellctl firmware_io tests csrc
	$(BIN)/mypy
	$(BIN)/lint-imports

# The core's tests again, against a build with AddressSanitizer and UBSan.
asan: $(STAMP)
	rm -rf asan-build && mkdir -p asan-build
	cp -r cellctl csrc tests asan-build/
	rm -f asan-build/cellctl/stereo/_core*.so
	cd asan-build && CELLCTL_CFLAGS="$(SANITIZE)" ../$(BIN)/python csrc/build_core.py >/dev/null
	cd asan-build && CELLCTL_MIDDLEBURY=$(CURDIR)/../shared/data/middlebury/2001-2003 ASAN_OPTIONS=detect_leaks=0 UBSAN_OPTIONS=print_stacktrace=1 \
		LD_PRELOAD="$$(gcc -print-file-name=libasan.so) $$(gcc -print-file-name=libubsan.so)" \
		../$(BIN)/python -m pytest -p no:cacheprovider -q tests/stereo

bench: $(STAMP)
	$(BIN)/cellctl bench

eval: $(STAMP)
	$(BIN)/cellctl eval middlebury --out out/middlebury

sysdeps:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing system packages:$$missing"; \
		$(SUDO) apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing; \
	fi

$(STAMP): pyproject.toml constraints.txt setup.py $(wildcard csrc/*.c csrc/*.h csrc/*.py)
	$(MAKE) sysdeps
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[test]'
	touch $@

clean:
	rm -rf build asan-build *.egg-info cellctl/stereo/_core*.so cellctl/stereo/_core.c out demo-out
